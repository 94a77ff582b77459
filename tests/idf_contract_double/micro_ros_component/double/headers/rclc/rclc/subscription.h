/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__SUBSCRIPTION_H_
#define RCLC__SUBSCRIPTION_H_
#include "rclc/types.h"
#include "rosidl_runtime_c/message_type_support_struct.h"
rcl_ret_t rclc_subscription_init_default(rcl_subscription_t * subscription, const rcl_node_t * node,
  const rosidl_message_type_support_t * type_support, const char * topic_name);
rcl_ret_t rclc_subscription_init_best_effort(rcl_subscription_t * subscription, const rcl_node_t * node,
  const rosidl_message_type_support_t * type_support, const char * topic_name);
#endif
