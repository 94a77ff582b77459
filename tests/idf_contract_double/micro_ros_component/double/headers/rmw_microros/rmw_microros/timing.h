/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__TIMING_H_
#define RMW_MICROROS__TIMING_H_
#include "rmw/types.h"
rmw_ret_t rmw_uros_set_context_entity_destroy_session_timeout(rmw_context_t * context, const int timeout_ms);
#endif
