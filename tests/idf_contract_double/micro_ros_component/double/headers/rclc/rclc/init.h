/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__INIT_H_
#define RCLC__INIT_H_
#include "rclc/types.h"
rcl_ret_t rclc_support_init_with_options(rclc_support_t * support, int argc, char const * const * argv,
  rcl_init_options_t * init_options, rcl_allocator_t * allocator);
rcl_ret_t rclc_support_fini(rclc_support_t * support);
#endif
