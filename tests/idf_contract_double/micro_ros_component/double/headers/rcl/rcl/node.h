/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__NODE_H_
#define RCL__NODE_H_
#include "rcl/context.h"
typedef struct rcl_node_s
{
  rcl_context_t * context;
  void * impl;
} rcl_node_t;
rcl_node_t rcl_get_zero_initialized_node(void);
rcl_ret_t rcl_node_fini(rcl_node_t * node);
#endif
