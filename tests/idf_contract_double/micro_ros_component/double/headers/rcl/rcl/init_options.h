/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__INIT_OPTIONS_H_
#define RCL__INIT_OPTIONS_H_
#include <stddef.h>
#include "rcl/allocator.h"
#include "rcl/types.h"
typedef struct rcl_init_options_s
{
  void * impl;
} rcl_init_options_t;
rcl_init_options_t rcl_get_zero_initialized_init_options(void);
rcl_ret_t rcl_init_options_init(rcl_init_options_t * init_options, rcl_allocator_t allocator);
rcl_ret_t rcl_init_options_fini(rcl_init_options_t * init_options);
rcl_ret_t rcl_init_options_set_domain_id(rcl_init_options_t * init_options, size_t domain_id);
rmw_init_options_t * rcl_init_options_get_rmw_init_options(rcl_init_options_t * init_options);
#endif
