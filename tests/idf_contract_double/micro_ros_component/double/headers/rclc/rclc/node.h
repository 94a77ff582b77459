/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__NODE_H_
#define RCLC__NODE_H_
#include "rclc/types.h"
rcl_ret_t rclc_node_init_default(rcl_node_t * node, const char * name, const char * namespace_,
  rclc_support_t * support);
#endif
