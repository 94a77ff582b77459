/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__INIT_OPTIONS_H_
#define RMW_MICROROS__INIT_OPTIONS_H_
#include "rmw/types.h"
rmw_ret_t rmw_uros_options_set_udp_address(const char * ip, const char * port, rmw_init_options_t * rmw_options);
#endif
