/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__SUBSCRIPTION_H_
#define RCL__SUBSCRIPTION_H_
#include "rcl/node.h"
typedef struct rcl_subscription_s
{
  void * impl;
} rcl_subscription_t;
rcl_subscription_t rcl_get_zero_initialized_subscription(void);
rcl_ret_t rcl_subscription_fini(rcl_subscription_t * subscription, rcl_node_t * node);
#endif
