/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__TYPES_H_
#define RCLC__TYPES_H_
#include "rcl/rcl.h"
typedef struct rclc_support_s
{
  rcl_init_options_t init_options;
  rcl_context_t context;
  rcl_allocator_t * allocator;
  rcl_clock_t * clock;
} rclc_support_t;
#endif
