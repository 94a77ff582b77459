/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__TIMER_H_
#define RCLC__TIMER_H_
#include <stdbool.h>
#include "rclc/types.h"
rcl_ret_t rclc_timer_init_default2(rcl_timer_t * timer, rclc_support_t * support, const uint64_t timeout_ns,
  const rcl_timer_callback_t callback, bool autostart);
#endif
