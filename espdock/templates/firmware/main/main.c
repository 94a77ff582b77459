/* @NAME@: a minimal micro-ROS app publishing a counter on /@NAME@/counter. */
#include <stdio.h>

#include "esp_log.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"

#include <rcl/rcl.h>
#include <rclc/executor.h>
#include <rclc/rclc.h>
#include <rmw_microros/rmw_microros.h>
#include <std_msgs/msg/int32.h>

#include "uros_network_interfaces.h"

static const char *TAG = "@NAME@";

#define RCCHECK(fn)                                                              \
  do {                                                                           \
    rcl_ret_t rc_ = (fn);                                                        \
    if (rc_ != RCL_RET_OK) {                                                     \
      ESP_LOGE(TAG, "%s failed (%d) at line %d", #fn, (int)rc_, __LINE__);       \
      vTaskDelete(NULL);                                                         \
    }                                                                            \
  } while (0)

static rcl_publisher_t publisher;
static std_msgs__msg__Int32 counter;

static void timer_callback(rcl_timer_t *timer, int64_t last_call_time) {
  (void)last_call_time;
  if (timer != NULL && rcl_publish(&publisher, &counter, NULL) == RCL_RET_OK) {
    counter.data++;
  }
}

static void micro_ros_task(void *arg) {
  (void)arg;
  rcl_allocator_t allocator = rcl_get_default_allocator();
  rcl_init_options_t init_options = rcl_get_zero_initialized_init_options();
  RCCHECK(rcl_init_options_init(&init_options, allocator));
  rmw_init_options_t *rmw_options = rcl_init_options_get_rmw_init_options(&init_options);
  RCCHECK(rmw_uros_options_set_udp_address(CONFIG_MICRO_ROS_AGENT_IP, CONFIG_MICRO_ROS_AGENT_PORT, rmw_options));

  rclc_support_t support;
  RCCHECK(rclc_support_init_with_options(&support, 0, NULL, &init_options, &allocator));
  rcl_node_t node;
  RCCHECK(rclc_node_init_default(&node, "@NAME@", "", &support));
  RCCHECK(rclc_publisher_init_default(&publisher, &node, ROSIDL_GET_MSG_TYPE_SUPPORT(std_msgs, msg, Int32),
                                      "@NAME@/counter"));
  rcl_timer_t timer;
  RCCHECK(rclc_timer_init_default2(&timer, &support, RCL_MS_TO_NS(1000), timer_callback, true));
  rclc_executor_t executor = rclc_executor_get_zero_initialized_executor();
  RCCHECK(rclc_executor_init(&executor, &support.context, 1, &allocator));
  RCCHECK(rclc_executor_add_timer(&executor, &timer));

  for (;;) {
    rclc_executor_spin_some(&executor, RCL_MS_TO_NS(100));
    vTaskDelay(pdMS_TO_TICKS(10));
  }
}

void app_main(void) {
  ESP_ERROR_CHECK(uros_network_interface_initialize());
  xTaskCreate(micro_ros_task, "micro_ros", 16000, NULL, 5, NULL);
}
