/* Wi-Fi station with endless, backed-off reconnection; see espdock_wifi.h. */
#include "espdock_wifi.h"

#include <string.h>

#include "esp_check.h"
#include "esp_event.h"
#include "esp_log.h"
#include "esp_netif.h"
#include "esp_timer.h"
#include "esp_wifi.h"
#include "espdock_net.h"
#include "freertos/FreeRTOS.h"
#include "freertos/event_groups.h"
#include "freertos/task.h"

#define CONNECTED_BIT BIT0
#define RETRY_MIN_MS 500u
#define RETRY_MAX_MS 30000u

static const char *TAG = "espdock_wifi";

static EventGroupHandle_t s_events;
static esp_timer_handle_t s_retry_timer;
static uint32_t s_retry_ms = RETRY_MIN_MS;

static void connect_now(void *arg)
{
    (void)arg;
    esp_err_t err = esp_wifi_connect();
    if (err != ESP_OK) {
        ESP_LOGW(TAG, "esp_wifi_connect: %s", esp_err_to_name(err));
    }
}

/* Reconnecting straight from the event handler spins when the AP refuses at
 * once (wrong password, MAC filter); back off up to RETRY_MAX_MS instead. */
static void schedule_reconnect(void)
{
    ESP_LOGW(TAG, "reconnecting in %u ms", (unsigned)s_retry_ms);
    (void)esp_timer_stop(s_retry_timer);    /* not running is fine */
    if (esp_timer_start_once(s_retry_timer, (uint64_t)s_retry_ms * 1000u) != ESP_OK) {
        connect_now(NULL);
    }
    s_retry_ms = s_retry_ms * 2u > RETRY_MAX_MS ? RETRY_MAX_MS : s_retry_ms * 2u;
}

static void on_wifi_event(void *arg, esp_event_base_t base, int32_t id, void *data)
{
    (void)arg;
    (void)base;
    if (id == WIFI_EVENT_STA_START) {
        connect_now(NULL);
    } else if (id == WIFI_EVENT_STA_DISCONNECTED) {
        const wifi_event_sta_disconnected_t *event = data;
        xEventGroupClearBits(s_events, CONNECTED_BIT);
        ESP_LOGW(TAG, "disconnected, reason %d", (int)event->reason);
        schedule_reconnect();
    }
}

static void on_ip_event(void *arg, esp_event_base_t base, int32_t id, void *data)
{
    (void)arg;
    (void)base;
    if (id == IP_EVENT_STA_GOT_IP) {
        const ip_event_got_ip_t *event = data;
        ESP_LOGI(TAG, "got IP " IPSTR, IP2STR(&event->ip_info.ip));
        s_retry_ms = RETRY_MIN_MS;
        xEventGroupSetBits(s_events, CONNECTED_BIT);
    } else if (id == IP_EVENT_STA_LOST_IP) {
        xEventGroupClearBits(s_events, CONNECTED_BIT);
    }
}

/* How far init_stack got: a retry after a failure resumes at the step that failed, since
 * creating the STA netif or the timer twice would abort. */
static int s_stage;

static esp_err_t init_stack(void)
{
    if (s_stage < 1) {
        ESP_RETURN_ON_ERROR(espdock_nvs_init(), TAG, "NVS init failed");
        ESP_RETURN_ON_ERROR(esp_netif_init(), TAG, "netif init failed");
        esp_err_t err = esp_event_loop_create_default();
        if (err != ESP_OK && err != ESP_ERR_INVALID_STATE) {    /* INVALID_STATE: already created */
            return err;
        }
        s_stage = 1;
    }
    if (s_stage < 2) {
        ESP_RETURN_ON_FALSE(esp_netif_create_default_wifi_sta() != NULL, ESP_FAIL, TAG, "no STA netif");
        s_stage = 2;
    }
    if (s_stage < 3) {
        wifi_init_config_t init = WIFI_INIT_CONFIG_DEFAULT();
        ESP_RETURN_ON_ERROR(esp_wifi_init(&init), TAG, "Wi-Fi init failed");
        /* The credentials live in the espdock NVS namespace only (espdock provision writes
         * them there); the driver's own NVS copy would outlive a re-provisioning. */
        ESP_RETURN_ON_ERROR(esp_wifi_set_storage(WIFI_STORAGE_RAM), TAG, "Wi-Fi storage");
        s_stage = 3;
    }
    if (s_stage < 4) {
        const esp_timer_create_args_t timer_args = {
            .callback = connect_now,
            .name = "wifi_retry",
        };
        ESP_RETURN_ON_ERROR(esp_timer_create(&timer_args, &s_retry_timer), TAG, "retry timer");
        ESP_RETURN_ON_ERROR(esp_event_handler_instance_register(WIFI_EVENT, ESP_EVENT_ANY_ID,
                                                                on_wifi_event, NULL, NULL),
                            TAG, "Wi-Fi handler");
        ESP_RETURN_ON_ERROR(esp_event_handler_instance_register(IP_EVENT, ESP_EVENT_ANY_ID,
                                                                on_ip_event, NULL, NULL),
                            TAG, "IP handler");
        s_stage = 4;
    }
    return ESP_OK;
}

esp_err_t espdock_wifi_start(const char *ssid, const char *password, bool power_save)
{
#if CONFIG_ESPDOCK_TRANSPORT_SERIAL
    /* The agent is on the serial line: the radio stays off (espdock_transport.h). */
    (void)ssid, (void)password, (void)power_save;
    return ESP_OK;
#endif
    wifi_config_t config;
    memset(&config, 0, sizeof config);
    size_t ssid_len = strlen(ssid);
    size_t password_len = strlen(password);
    /* The driver takes a 32-byte SSID and 64-byte key without a terminator. */
    ESP_RETURN_ON_FALSE(ssid_len > 0 && ssid_len <= sizeof config.sta.ssid, ESP_ERR_INVALID_ARG,
                        TAG, "SSID must be 1..32 bytes");
    ESP_RETURN_ON_FALSE(password_len <= sizeof config.sta.password, ESP_ERR_INVALID_ARG,
                        TAG, "password must be at most 64 bytes");
    memcpy(config.sta.ssid, ssid, ssid_len);
    memcpy(config.sta.password, password, password_len);
    /* With a password set, refuse open or WEP networks that merely share the SSID. */
    config.sta.threshold.authmode = password_len > 0 ? WIFI_AUTH_WPA2_PSK : WIFI_AUTH_OPEN;

    if (s_events == NULL) {
        s_events = xEventGroupCreate();
    }
    ESP_RETURN_ON_FALSE(s_events != NULL, ESP_ERR_NO_MEM, TAG, "event group");
    ESP_RETURN_ON_ERROR(init_stack(), TAG, "network stack");
    ESP_RETURN_ON_ERROR(esp_wifi_set_mode(WIFI_MODE_STA), TAG, "station mode");
    ESP_RETURN_ON_ERROR(esp_wifi_set_config(WIFI_IF_STA, &config), TAG, "station config");
    ESP_RETURN_ON_ERROR(esp_wifi_start(), TAG, "Wi-Fi start");
    /* Modem sleep holds inbound packets until the next beacon, which stalls
     * XRCE acknowledgements and with them every reliable publish. */
    ESP_RETURN_ON_ERROR(esp_wifi_set_ps(power_save ? WIFI_PS_MIN_MODEM : WIFI_PS_NONE), TAG,
                        "power save");
    ESP_LOGI(TAG, "connecting to \"%s\"", ssid);
    return ESP_OK;
}

void espdock_wifi_start_retrying(const char *ssid, const char *password, bool power_save)
{
    uint32_t delay_ms = RETRY_MIN_MS;
    esp_err_t err;
    while ((err = espdock_wifi_start(ssid, password, power_save)) != ESP_OK) {
        ESP_LOGE(TAG, "Wi-Fi start failed: %s; retrying in %u ms", esp_err_to_name(err), (unsigned)delay_ms);
        vTaskDelay(pdMS_TO_TICKS(delay_ms));
        delay_ms = delay_ms * 2u > RETRY_MAX_MS ? RETRY_MAX_MS : delay_ms * 2u;
    }
}

bool espdock_wifi_is_connected(void)
{
    return s_events != NULL && (xEventGroupGetBits(s_events) & CONNECTED_BIT) != 0;
}

bool espdock_wifi_wait_connected(uint32_t timeout_ms)
{
    if (s_events == NULL) {
        return false;
    }
    EventBits_t bits = xEventGroupWaitBits(s_events, CONNECTED_BIT, pdFALSE, pdTRUE,
                                           pdMS_TO_TICKS(timeout_ms));
    return (bits & CONNECTED_BIT) != 0;
}
