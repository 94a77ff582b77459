/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__TIMER_H_
#define RCL__TIMER_H_
#include "rcl/time.h"
#include "rcl/types.h"
typedef struct rcl_timer_s
{
  void * impl;
} rcl_timer_t;
typedef void (* rcl_timer_callback_t)(rcl_timer_t *, int64_t);
rcl_timer_t rcl_get_zero_initialized_timer(void);
rcl_ret_t rcl_timer_fini(rcl_timer_t * timer);
#endif
