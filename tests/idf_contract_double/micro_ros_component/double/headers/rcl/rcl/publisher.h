/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__PUBLISHER_H_
#define RCL__PUBLISHER_H_
#include "rcl/node.h"
#include "rmw/qos_profiles.h"
typedef struct rcl_publisher_s
{
  void * impl;
} rcl_publisher_t;
rcl_publisher_t rcl_get_zero_initialized_publisher(void);
rcl_ret_t rcl_publish(const rcl_publisher_t * publisher, const void * ros_message, void * allocation);
rcl_ret_t rcl_publisher_fini(rcl_publisher_t * publisher, rcl_node_t * node);
#endif
