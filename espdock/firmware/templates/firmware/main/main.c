/* @NAME@: a micro-ROS app publishing a counter on /@NAME@/counter once a second.
 *
 * espdock_uros keeps Wi-Fi and the agent session alive: when the agent goes
 * away the entities are destroyed, and created again when it comes back. */
#include <rclc/executor.h>
#include <std_msgs/msg/int32.h>

#include "esp_log.h"
#include "espdock_uros.h"
#include "espdock_net.h"
#include "espdock_wifi.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "sdkconfig.h"

/* espdock_uros talks to the agent over UDP on Wi-Fi, as upstream's examples do only under
 * these options, or over a serial line (espdock micro-ROS transport): any other middleware
 * or network interface needs another app. */
#if !defined(CONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE)
#error "@NAME@ needs micro-ROS over Micro XRCE-DDS (micro-ROS Settings > middleware)"
#endif
#if !defined(CONFIG_MICRO_ROS_ESP_NETIF_WLAN) && !defined(CONFIG_ESPDOCK_TRANSPORT_SERIAL)
#error "@NAME@ reaches the agent over Wi-Fi: select micro-ROS Settings > WLAN interface"
#endif

static const char *TAG = "@NAME@";

typedef struct {
    espdock_uros_t uros;
    rcl_publisher_t publisher;
    rcl_timer_t timer;
    rclc_executor_t executor;
    std_msgs__msg__Int32 counter;
} app_node_t;

/* rclc timer callbacks carry no user pointer, hence one static node. */
static app_node_t s_node;
/* Read once at boot (NVS, else Kconfig); the micro-ROS task reads it afterwards. */
static net_settings_t s_net;

static void on_timer(rcl_timer_t *timer, int64_t last_call_time)
{
    (void)last_call_time;
    if (timer == NULL) {
        return;
    }
    ESPDOCK_RC_SOFTCHECK(rcl_publish(&s_node.publisher, &s_node.counter, NULL));
    s_node.counter.data++;
}

static bool create_entities(void *ctx)
{
    app_node_t *node = ctx;
    node->publisher = rcl_get_zero_initialized_publisher();
    node->timer = rcl_get_zero_initialized_timer();
    node->executor = rclc_executor_get_zero_initialized_executor();
    if (!espdock_uros_open(&node->uros)) {
        return false;
    }
    ESPDOCK_RC_CHECK(rclc_publisher_init_default(&node->publisher, &node->uros.node,
                                                 ROSIDL_GET_MSG_TYPE_SUPPORT(std_msgs, msg, Int32),
                                                 "@NAME@/counter"));
    ESPDOCK_RC_CHECK(rclc_timer_init_default2(&node->timer, &node->uros.support, RCL_MS_TO_NS(1000),
                                              on_timer, true));
    ESPDOCK_RC_CHECK(rclc_executor_init(&node->executor, &node->uros.support.context, 1,
                                        &node->uros.allocator));
    ESPDOCK_RC_CHECK(rclc_executor_add_timer(&node->executor, &node->timer));
    return true;
}

static void destroy_entities(void *ctx)
{
    app_node_t *node = ctx;
    espdock_uros_begin_teardown(&node->uros);
    /* Failures are expected for entities a failed creation never made. */
    (void)rclc_executor_fini(&node->executor);
    (void)rcl_timer_fini(&node->timer);
    (void)rcl_publisher_fini(&node->publisher, &node->uros.node);
    espdock_uros_close(&node->uros);
}

static void spin(void *ctx)
{
    app_node_t *node = ctx;
    (void)rclc_executor_spin_some(&node->executor, RCL_MS_TO_NS(10));
}

static void uros_task(void *arg)
{
    (void)arg;
    const espdock_uros_config_t config = {
        .agent_ip = s_net.agent_host,
        .agent_port = s_net.agent_port,
        .domain_id = s_net.domain_id,
        .node_name = "@NAME@",
        .node_namespace = "",
    };
    const espdock_uros_app_t app = {
        .create_entities = create_entities,
        .destroy_entities = destroy_entities,
        .spin = spin,
        .ctx = &s_node,
    };
    espdock_uros_serve(&s_node.uros, &config, app, 10);
}

void app_main(void)
{
    espdock_net_load(&s_net);
    /* Like the agent link, Wi-Fi that fails to start (NVS, memory) is retried, not given up. */
    espdock_wifi_start_retrying(s_net.ssid, s_net.password, false);
    if (xTaskCreate(uros_task, "uros", CONFIG_ESPDOCK_UROS_TASK_STACK, NULL, 5, NULL) != pdPASS) {
        ESP_LOGE(TAG, "could not start the micro-ROS task (stack %d B)", CONFIG_ESPDOCK_UROS_TASK_STACK);
    }
}
