/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__EXECUTOR_H_
#define RCLC__EXECUTOR_H_
#include <stddef.h>
#include <stdint.h>
#include "rclc/types.h"
typedef enum
{
  ON_NEW_DATA,
  ALWAYS
} rclc_executor_handle_invocation_t;
typedef void (* rclc_subscription_callback_t)(const void *);
typedef void (* rclc_service_callback_t)(const void *, void *);
typedef struct rclc_executor_s
{
  rcl_context_t * context;
  void * handles;
  size_t max_handles;
  size_t index;
  const rcl_allocator_t * allocator;
} rclc_executor_t;
rclc_executor_t rclc_executor_get_zero_initialized_executor(void);
rcl_ret_t rclc_executor_init(rclc_executor_t * executor, rcl_context_t * context,
  const size_t number_of_handles, const rcl_allocator_t * allocator);
rcl_ret_t rclc_executor_fini(rclc_executor_t * executor);
rcl_ret_t rclc_executor_add_timer(rclc_executor_t * executor, rcl_timer_t * timer);
rcl_ret_t rclc_executor_add_subscription(rclc_executor_t * executor, rcl_subscription_t * subscription,
  void * msg, rclc_subscription_callback_t callback, rclc_executor_handle_invocation_t invocation);
rcl_ret_t rclc_executor_add_service(rclc_executor_t * executor, rcl_service_t * service,
  void * request_msg, void * response_msg, rclc_service_callback_t callback);
rcl_ret_t rclc_executor_spin_some(rclc_executor_t * executor, const uint64_t timeout_ns);
#endif
