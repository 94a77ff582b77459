/*
 * camera_node: publishes the ESP32 camera's JPEG frames as
 * sensor_msgs/CompressedImage and serves the camera settings through
 * custom_interface Get/SetCameraConfig, over micro-ROS (seed chapter 7.2).
 */
#include <string.h>

#include <custom_interface/srv/get_camera_config.h>
#include <custom_interface/srv/set_camera_config.h>
#include <rcl/rcl.h>
#include <rclc/executor.h>
#include <rclc/rclc.h>
#include <sensor_msgs/msg/compressed_image.h>

#include "camera_config.h"
#include "camera_hw.h"
#include "esp_camera.h"
#include "esp_log.h"
#include "esp_timer.h"
#include "espdock_uros.h"
#include "espdock_net.h"
#include "espdock_wifi.h"
#include "frame_pacer.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "sdkconfig.h"

#define EXECUTOR_HANDLES 3      /* publish timer + get_config + set_config */
#define TIMER_PERIOD_MS 10      /* ticks faster than any frame rate; the pacer picks ticks */
#define SPIN_TIMEOUT_MS 10
#define CAMERA_RETRY_MS 5000

#if CONFIG_FREERTOS_UNICORE
#define UROS_TASK_CORE 0
#else
#define UROS_TASK_CORE 1        /* APP_CPU: PRO_CPU keeps Wi-Fi and the camera driver */
#endif

static const char *TAG = "camera_node";

typedef struct {
    espdock_uros_t uros;
    rcl_publisher_t image_pub;
    rcl_service_t get_srv;
    rcl_service_t set_srv;
    rcl_timer_t timer;
    rclc_executor_t executor;
    custom_interface__srv__GetCameraConfig_Request get_req;
    custom_interface__srv__GetCameraConfig_Response get_res;
    custom_interface__srv__SetCameraConfig_Request set_req;
    custom_interface__srv__SetCameraConfig_Response set_res;
    sensor_msgs__msg__CompressedImage image;
    frame_pacer_t pacer;
} camera_node_t;

/* rclc timer and service callbacks carry no user pointer, hence one static node. */
static camera_node_t s_node;
/* Read once at boot (NVS, else Kconfig); the micro-ROS task reads it afterwards. */
static net_settings_t s_net;
static char s_frame_id[] = CONFIG_ESPDOCK_CAM_FRAME_ID;
static char s_format[] = "jpeg";

/* Points a message string at static text: serialisation only reads it. */
static void use_static_string(rosidl_runtime_c__String *str, char *text)
{
    str->data = text;
    str->size = strlen(text);
    str->capacity = str->size + 1;
}

static void cfg_to_msg(custom_interface__msg__CameraConfig *dst, const cam_cfg_t *src)
{
#define COPY_FIELD(name, ...) dst->name = src->name;
    CAM_CFG_FIELDS(COPY_FIELD)
#undef COPY_FIELD
}

static void cfg_from_msg(cam_cfg_t *dst, const custom_interface__msg__CameraConfig *src)
{
#define COPY_FIELD(name, ...) dst->name = src->name;
    CAM_CFG_FIELDS(COPY_FIELD)
#undef COPY_FIELD
}

/* Fills msg with the sensor's settings, or zeros if the camera stopped. */
static void report_current(custom_interface__msg__CameraConfig *msg)
{
    cam_cfg_t current;
    if (!camera_hw_read(&current)) {
        ESP_LOGW(TAG, "camera not running; reporting zeros");
        memset(&current, 0, sizeof current);
    }
    cfg_to_msg(msg, &current);
}

static void publish_frame(rcl_timer_t *timer, int64_t last_call_time)
{
    (void)last_call_time;
    if (timer == NULL || !frame_pacer_should_publish(&s_node.pacer, esp_timer_get_time() * 1000)) {
        return;
    }
    camera_fb_t *fb = esp_camera_fb_get();
    if (fb == NULL) {
        ESP_LOGW(TAG, "frame capture failed");
        return;
    }
    if (fb->format == PIXFORMAT_JPEG) {
        espdock_uros_stamp(&s_node.image.header.stamp);
        s_node.image.data.data = fb->buf;
        s_node.image.data.size = fb->len;
        s_node.image.data.capacity = fb->len;
        ESP_LOGD(TAG, "frame %ux%u, %u B", (unsigned)fb->width, (unsigned)fb->height,
                 (unsigned)fb->len);
        ESPDOCK_RC_SOFTCHECK(rcl_publish(&s_node.image_pub, &s_node.image, NULL));
        s_node.image.data.data = NULL;
        s_node.image.data.size = 0;
        s_node.image.data.capacity = 0;
    } else {
        ESP_LOGW(TAG, "dropping a frame in pixel format %d", (int)fb->format);
    }
    /* Always hand the buffer back: with two buffers the driver stalls after two leaks. */
    esp_camera_fb_return(fb);
}

static void get_config(const void *req, void *res)
{
    (void)req;
    custom_interface__srv__GetCameraConfig_Response *response = res;
    report_current(&response->config);
}

static void set_config(const void *req, void *res)
{
    const custom_interface__srv__SetCameraConfig_Request *request = req;
    custom_interface__srv__SetCameraConfig_Response *response = res;
    cam_cfg_t wanted;
    cam_field_t bad = CAM_FIELD_COUNT;
    cfg_from_msg(&wanted, &request->config);
    if (!cam_cfg_validate(&wanted, CONFIG_ESPDOCK_CAM_MAX_FRAMESIZE_VALUE, &bad)) {
        /* All or nothing: one field out of range refuses the whole request. */
        const cam_field_info_t *info = cam_field_info(bad);
        ESP_LOGW(TAG, "set_config refused: %s=%d out of range", info->name,
                 (int)cam_cfg_get(&wanted, bad));
        response->status = false;
    } else {
        cam_apply_result_t result = camera_hw_apply(&wanted);
        ESP_LOGI(TAG, "set_config: %u applied, %u refused by the sensor", result.applied,
                 result.failed);
        response->status = result.failed == 0u;
    }
    report_current(&response->config);
}

static bool create_entities(void *ctx)
{
    camera_node_t *node = ctx;
    /* Zeroed handles make destroy_entities safe after a partial creation. */
    node->image_pub = rcl_get_zero_initialized_publisher();
    node->get_srv = rcl_get_zero_initialized_service();
    node->set_srv = rcl_get_zero_initialized_service();
    node->timer = rcl_get_zero_initialized_timer();
    node->executor = rclc_executor_get_zero_initialized_executor();
    if (!espdock_uros_open(&node->uros)) {
        return false;
    }
    /* Reliable (default QoS), not best effort: only reliable XRCE streams
     * fragment, and a frame spans many MTUs (sizing in app-colcon.meta /
     * README). Reliable publishers also serve best-effort subscribers. */
    ESPDOCK_RC_CHECK(rclc_publisher_init_default(
        &node->image_pub, &node->uros.node,
        ROSIDL_GET_MSG_TYPE_SUPPORT(sensor_msgs, msg, CompressedImage),
        CONFIG_ESPDOCK_CAM_IMAGE_TOPIC));
    ESPDOCK_RC_CHECK(rclc_service_init_default(
        &node->get_srv, &node->uros.node,
        ROSIDL_GET_SRV_TYPE_SUPPORT(custom_interface, srv, GetCameraConfig),
        CONFIG_ESPDOCK_CAM_GET_CONFIG_SERVICE));
    ESPDOCK_RC_CHECK(rclc_service_init_default(
        &node->set_srv, &node->uros.node,
        ROSIDL_GET_SRV_TYPE_SUPPORT(custom_interface, srv, SetCameraConfig),
        CONFIG_ESPDOCK_CAM_SET_CONFIG_SERVICE));
    ESPDOCK_RC_CHECK(rclc_timer_init_default2(&node->timer, &node->uros.support,
                                              RCL_MS_TO_NS(TIMER_PERIOD_MS), publish_frame, true));
    ESPDOCK_RC_CHECK(rclc_executor_init(&node->executor, &node->uros.support.context,
                                        EXECUTOR_HANDLES, &node->uros.allocator));
    ESPDOCK_RC_CHECK(rclc_executor_add_timer(&node->executor, &node->timer));
    ESPDOCK_RC_CHECK(rclc_executor_add_service(&node->executor, &node->get_srv, &node->get_req,
                                               &node->get_res, get_config));
    ESPDOCK_RC_CHECK(rclc_executor_add_service(&node->executor, &node->set_srv, &node->set_req,
                                               &node->set_res, set_config));
    frame_pacer_init(&node->pacer, CONFIG_ESPDOCK_CAM_MAX_FPS);
    return true;
}

static void destroy_entities(void *ctx)
{
    camera_node_t *node = ctx;
    espdock_uros_begin_teardown(&node->uros);
    /* Failures are expected for entities a failed creation never made. */
    (void)rclc_executor_fini(&node->executor);
    (void)rcl_timer_fini(&node->timer);
    (void)rcl_service_fini(&node->set_srv, &node->uros.node);
    (void)rcl_service_fini(&node->get_srv, &node->uros.node);
    (void)rcl_publisher_fini(&node->image_pub, &node->uros.node);
    espdock_uros_close(&node->uros);
}

static void spin(void *ctx)
{
    camera_node_t *node = ctx;
    espdock_uros_keep_clock(&node->uros);
    /* RCL_RET_TIMEOUT (nothing to do) is the common case, not an error. */
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
    espdock_uros_serve(&s_node.uros, &config, app, 1);
}

void app_main(void)
{
    /* A loose ribbon cable or a brown-out at power-up can fail the first
     * probe; keep trying rather than boot-looping. */
    while (camera_hw_init(CONFIG_ESPDOCK_CAM_MAX_FRAMESIZE_VALUE, CONFIG_ESPDOCK_CAM_JPEG_QUALITY)
           != ESP_OK) {
        ESP_LOGE(TAG, "camera init failed; retrying in %d ms", CAMERA_RETRY_MS);
        vTaskDelay(pdMS_TO_TICKS(CAMERA_RETRY_MS));
    }
    espdock_net_load(&s_net);
    /* Like the agent link, Wi-Fi that fails to start (NVS, memory) is retried, not given up. */
    espdock_wifi_start_retrying(s_net.ssid, s_net.password, false);
    use_static_string(&s_node.image.header.frame_id, s_frame_id);
    use_static_string(&s_node.image.format, s_format);
    if (xTaskCreatePinnedToCore(uros_task, "uros", CONFIG_ESPDOCK_UROS_TASK_STACK, NULL,
                                CONFIG_ESPDOCK_UROS_TASK_PRIORITY, NULL, UROS_TASK_CORE) != pdPASS) {
        ESP_LOGE(TAG, "could not start the micro-ROS task (stack %d B)", CONFIG_ESPDOCK_UROS_TASK_STACK);
    }
}
