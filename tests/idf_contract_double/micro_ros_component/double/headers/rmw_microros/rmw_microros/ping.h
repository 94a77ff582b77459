/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__PING_H_
#define RMW_MICROROS__PING_H_
#include <stdint.h>
#include "rmw/types.h"
rmw_ret_t rmw_uros_ping_agent(const int timeout_ms, const uint8_t attempts);
rmw_ret_t rmw_uros_ping_agent_options(const int timeout_ms, const uint8_t attempts, rmw_init_options_t * rmw_options);
#endif
