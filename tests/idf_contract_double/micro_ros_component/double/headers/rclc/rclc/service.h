/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__SERVICE_H_
#define RCLC__SERVICE_H_
#include "rclc/types.h"
#include "rosidl_runtime_c/service_type_support_struct.h"
rcl_ret_t rclc_service_init_default(rcl_service_t * service, const rcl_node_t * node,
  const rosidl_service_type_support_t * type_support, const char * service_name);
#endif
