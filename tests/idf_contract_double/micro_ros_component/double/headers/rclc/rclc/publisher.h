/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__PUBLISHER_H_
#define RCLC__PUBLISHER_H_
#include "rclc/types.h"
#include "rosidl_runtime_c/message_type_support_struct.h"
rcl_ret_t rclc_publisher_init_default(rcl_publisher_t * publisher, const rcl_node_t * node,
  const rosidl_message_type_support_t * type_support, const char * topic_name);
rcl_ret_t rclc_publisher_init(rcl_publisher_t * publisher, const rcl_node_t * node,
  const rosidl_message_type_support_t * type_support, const char * topic_name,
  const rmw_qos_profile_t * qos_profile);
#endif
