/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__CONTEXT_H_
#define RCL__CONTEXT_H_
#include <stdbool.h>
#include "rcl/init_options.h"
typedef struct rcl_context_s
{
  void * global_arguments;
  void * impl;
} rcl_context_t;
rcl_context_t rcl_get_zero_initialized_context(void);
bool rcl_context_is_valid(const rcl_context_t * context);
rmw_context_t * rcl_context_get_rmw_context(rcl_context_t * context);
#endif
