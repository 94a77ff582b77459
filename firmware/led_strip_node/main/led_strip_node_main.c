/*
 * led_strip_node: sets an addressable LED strip to the "#RGB"/"#RRGGBB"
 * colour received on /qr_message and publishes the strip's colour as
 * std_msgs/ColorRGBA, over micro-ROS (seed chapter 7.5).
 */
#include <string.h>

#include <rcl/rcl.h>
#include <rclc/executor.h>
#include <rclc/rclc.h>
#include <rmw/qos_profiles.h>
#include <std_msgs/msg/color_rgba.h>
#include <std_msgs/msg/string.h>

#include "color_parse.h"
#include "esp_check.h"
#include "esp_log.h"
#include "espdock_uros.h"
#include "espdock_net.h"
#include "espdock_wifi.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "led_strip.h"
#include "sdkconfig.h"

#define EXECUTOR_HANDLES 1      /* the colour subscription */
#define SPIN_TIMEOUT_MS 50      /* a non-critical node: spin slower than the camera */
#define RMT_RESOLUTION_HZ (10 * 1000 * 1000)   /* 0.1 us ticks for the LED bit timing */
/* A colour is at most 7 characters; micro-ROS drops strings that do not fit,
 * so long QR payloads never reach the parser. */
#define RX_CAPACITY 64

#if CONFIG_ESPDOCK_LED_MODEL_SK6812
#define STRIP_MODEL LED_MODEL_SK6812
#elif CONFIG_ESPDOCK_LED_MODEL_WS2811
#define STRIP_MODEL LED_MODEL_WS2811
#else
#define STRIP_MODEL LED_MODEL_WS2812
#endif

#if CONFIG_ESPDOCK_LED_ORDER_RGB
#define STRIP_ORDER LED_STRIP_COLOR_COMPONENT_FMT_RGB
#else
#define STRIP_ORDER LED_STRIP_COLOR_COMPONENT_FMT_GRB
#endif

#if CONFIG_FREERTOS_UNICORE
#define UROS_TASK_CORE 0
#else
#define UROS_TASK_CORE 1
#endif

static const char *TAG = "led_strip_node";

typedef struct {
    espdock_uros_t uros;
    rcl_subscription_t color_sub;
    rcl_publisher_t state_pub;
    rclc_executor_t executor;
    std_msgs__msg__String rx;
    led_strip_handle_t strip;
    rgb8_t shown;               /* what the strip displays */
    bool shown_known;           /* false after a failed refresh: state unknown */
} led_node_t;

/* rclc subscription callbacks carry no user pointer, hence one static node. */
static led_node_t s_node;
/* Read once at boot (NVS, else Kconfig); the micro-ROS task reads it afterwards. */
static net_settings_t s_net;
static char s_rx_buffer[RX_CAPACITY];

static esp_err_t strip_init(led_strip_handle_t *strip)
{
    const led_strip_config_t strip_config = {
        .strip_gpio_num = CONFIG_ESPDOCK_LED_STRIP_GPIO,
        .max_leds = CONFIG_ESPDOCK_LED_COUNT,
        .led_model = STRIP_MODEL,
        .color_component_format = STRIP_ORDER,
    };
    const led_strip_rmt_config_t rmt_config = {
        .clk_src = RMT_CLK_SRC_DEFAULT,
        .resolution_hz = RMT_RESOLUTION_HZ,
        .mem_block_symbols = 0,     /* let the driver pick */
    };
    return led_strip_new_rmt_device(&strip_config, &rmt_config, strip);
}

static esp_err_t strip_fill(led_strip_handle_t strip, rgb8_t color)
{
    for (uint32_t i = 0; i < CONFIG_ESPDOCK_LED_COUNT; i++) {
        ESP_RETURN_ON_ERROR(led_strip_set_pixel(strip, i, color.r, color.g, color.b), TAG,
                            "pixel %u", (unsigned)i);
    }
    return led_strip_refresh(strip);
}

static void publish_shown(led_node_t *node)
{
    if (!node->shown_known) {
        return;
    }
    std_msgs__msg__ColorRGBA msg = {
        .r = color_channel_to_unit(node->shown.r),
        .g = color_channel_to_unit(node->shown.g),
        .b = color_channel_to_unit(node->shown.b),
        .a = 1.0f,
    };
    ESPDOCK_RC_SOFTCHECK(rcl_publish(&node->state_pub, &msg, NULL));
}

static void on_color_text(const void *msgin)
{
    const std_msgs__msg__String *msg = msgin;
    rgb8_t color;
    color_status_t status = color_parse_hex(msg->data.data, msg->data.size, &color);
    if (status != COLOR_OK) {
        ESP_LOGI(TAG, "ignoring \"%.*s\": %s", (int)(msg->data.size < 32 ? msg->data.size : 32),
                 msg->data.data != NULL ? msg->data.data : "", color_status_name(status));
        return;
    }
    if (s_node.shown_known && color_equal(color, s_node.shown)) {
        return;     /* the QR detector repeats itself; nothing changes */
    }
    if (s_node.strip == NULL) {
        ESP_LOGW(TAG, "LED strip not initialised; ignoring colour");
        return;
    }
    esp_err_t err = strip_fill(s_node.strip, color);
    if (err != ESP_OK) {
        /* Leave the state unknown so the same colour is tried again next time. */
        ESP_LOGW(TAG, "LED strip update failed: %s", esp_err_to_name(err));
        s_node.shown_known = false;
        return;
    }
    ESP_LOGI(TAG, "colour #%02x%02x%02x", color.r, color.g, color.b);
    s_node.shown = color;
    s_node.shown_known = true;
    publish_shown(&s_node);
}

static bool create_entities(void *ctx)
{
    led_node_t *node = ctx;
    node->color_sub = rcl_get_zero_initialized_subscription();
    node->state_pub = rcl_get_zero_initialized_publisher();
    node->executor = rclc_executor_get_zero_initialized_executor();
    if (!espdock_uros_open(&node->uros)) {
        return false;
    }
    /* Best effort: a /qr_message longer than one datagram (512 B MTU) is dropped by the agent.
     * On the reliable input stream (2 slots of 512 B) a message over its 1024 B could never be
     * reassembled and would jam the stream for good while pings kept the session "connected";
     * see firmware/README.md. Colours are 4 or 7 characters. */
    ESPDOCK_RC_CHECK(rclc_subscription_init_best_effort(
        &node->color_sub, &node->uros.node, ROSIDL_GET_MSG_TYPE_SUPPORT(std_msgs, msg, String),
        CONFIG_ESPDOCK_LED_COLOR_TOPIC));
    /* Transient local, depth 1: a subscriber that starts later still gets the
     * strip's current colour. */
    rmw_qos_profile_t qos = rmw_qos_profile_default;
    qos.durability = RMW_QOS_POLICY_DURABILITY_TRANSIENT_LOCAL;
    qos.history = RMW_QOS_POLICY_HISTORY_KEEP_LAST;
    qos.depth = 1;
    ESPDOCK_RC_CHECK(rclc_publisher_init(
        &node->state_pub, &node->uros.node, ROSIDL_GET_MSG_TYPE_SUPPORT(std_msgs, msg, ColorRGBA),
        CONFIG_ESPDOCK_LED_STATE_TOPIC, &qos));
    ESPDOCK_RC_CHECK(rclc_executor_init(&node->executor, &node->uros.support.context,
                                        EXECUTOR_HANDLES, &node->uros.allocator));
    ESPDOCK_RC_CHECK(rclc_executor_add_subscription(&node->executor, &node->color_sub, &node->rx,
                                                    on_color_text, ON_NEW_DATA));
    /* A new session means a new publisher with an empty history: re-announce. */
    publish_shown(node);
    return true;
}

static void destroy_entities(void *ctx)
{
    led_node_t *node = ctx;
    espdock_uros_begin_teardown(&node->uros);
    /* Failures are expected for entities a failed creation never made. */
    (void)rclc_executor_fini(&node->executor);
    (void)rcl_publisher_fini(&node->state_pub, &node->uros.node);
    (void)rcl_subscription_fini(&node->color_sub, &node->uros.node);
    espdock_uros_close(&node->uros);
}

static void spin(void *ctx)
{
    led_node_t *node = ctx;
    (void)rclc_executor_spin_some(&node->executor, RCL_MS_TO_NS(SPIN_TIMEOUT_MS));
}

static void uros_task(void *arg)
{
    (void)arg;
    const espdock_uros_config_t config = {
        .agent_ip = s_net.agent_host,
        .agent_port = s_net.agent_port,
        .domain_id = s_net.domain_id,
        .node_name = CONFIG_ESPDOCK_NODE_NAME,
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
    s_node.rx.data.data = s_rx_buffer;
    s_node.rx.data.size = 0;
    s_node.rx.data.capacity = sizeof s_rx_buffer;

    /* Without a strip the node still joins the graph, so the failure shows
     * up in the logs and in the missing colour topic, not as a boot loop. */
    s_node.strip = NULL;
    esp_err_t err = strip_init(&s_node.strip);
    if (err != ESP_OK) {
        ESP_LOGE(TAG, "LED strip on GPIO %d unavailable: %s", CONFIG_ESPDOCK_LED_STRIP_GPIO,
                 esp_err_to_name(err));
        s_node.strip = NULL;
    } else if (led_strip_clear(s_node.strip) == ESP_OK) {
        /* Strips keep their colour across an ESP32 reset: start from a known "off". */
        s_node.shown = (rgb8_t){0, 0, 0};
        s_node.shown_known = true;
    }
    espdock_net_load(&s_net);
    /* Like the agent link, Wi-Fi that fails to start (NVS, memory) is retried, not given up. */
    espdock_wifi_start_retrying(s_net.ssid, s_net.password, false);
    if (xTaskCreatePinnedToCore(uros_task, "uros", CONFIG_ESPDOCK_UROS_TASK_STACK, NULL,
                                CONFIG_ESPDOCK_UROS_TASK_PRIORITY, NULL, UROS_TASK_CORE) != pdPASS) {
        ESP_LOGE(TAG, "could not start the micro-ROS task (stack %d B)", CONFIG_ESPDOCK_UROS_TASK_STACK);
    }
}
