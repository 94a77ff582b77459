/* Reading the provisioned network settings from NVS; see espdock_net.h. */
#include "espdock_net.h"
#include "espdock_transport.h"

#include <string.h>

#include "esp_log.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "nvs.h"
#include "nvs_flash.h"
#include "sdkconfig.h"

#define RETRY_MS 10000u

static const char *TAG = "espdock_net";

/* Room for one more byte than allowed, so an over-long value reads as over-long, not as missing. */
typedef struct {
    char ssid[NET_SSID_MAX + 2];
    char password[NET_PASSWORD_MAX + 2];
    char agent_host[NET_HOST_MAX + 2];
} nvs_strings_t;

/* A key of another type (ESP_ERR_NVS_TYPE_MISMATCH: written by hand, not by espdock provision)
 * is ignored like a missing one, but said: otherwise the build's fallback wins in silence. */
static void log_unreadable(const char *key, const char *type, esp_err_t err)
{
    if (err == ESP_OK || err == ESP_ERR_NVS_NOT_FOUND) {
        return;
    }
    if (err == ESP_ERR_NVS_TYPE_MISMATCH) {
        ESP_LOGW(TAG, "NVS key %s is not %s (as espdock provision writes it): ignored", key, type);
    } else {
        ESP_LOGW(TAG, "NVS key %s unreadable: %s", key, esp_err_to_name(err));
    }
}

static const char *read_str(nvs_handle_t handle, const char *key, char *buf, size_t size)
{
    size_t len = size;
    esp_err_t err = nvs_get_str(handle, key, buf, &len);
    if (err == ESP_OK) {
        return buf;
    }
    if (err == ESP_ERR_NVS_INVALID_LENGTH) {
        /* Too long for the buffer: hand the checks a value they refuse, by length. */
        memset(buf, 'x', size - 1);
        buf[size - 1] = '\0';
        return buf;
    }
    log_unreadable(key, "a string", err);
    return NULL;
}

static void read_nvs(net_candidate_t *nvs, nvs_strings_t *strings)
{
    memset(nvs, 0, sizeof *nvs);
    nvs_handle_t handle;
    esp_err_t err = nvs_open(NET_NVS_NAMESPACE, NVS_READONLY, &handle);
    if (err == ESP_ERR_NVS_NOT_FOUND) {
        return;    /* never provisioned */
    }
    if (err != ESP_OK) {
        ESP_LOGW(TAG, "NVS namespace %s unreadable: %s", NET_NVS_NAMESPACE, esp_err_to_name(err));
        return;
    }
    nvs->ssid = read_str(handle, NET_KEY_SSID, strings->ssid, sizeof strings->ssid);
    nvs->password = read_str(handle, NET_KEY_PASSWORD, strings->password, sizeof strings->password);
    nvs->agent_host = read_str(handle, NET_KEY_AGENT_HOST, strings->agent_host, sizeof strings->agent_host);
    uint16_t port;
    err = nvs_get_u16(handle, NET_KEY_AGENT_PORT, &port);
    if (err == ESP_OK) {
        nvs->has_agent_port = true;
        nvs->agent_port = port;
    }
    log_unreadable(NET_KEY_AGENT_PORT, "a u16", err);
    uint8_t domain;
    err = nvs_get_u8(handle, NET_KEY_DOMAIN_ID, &domain);
    if (err == ESP_OK) {
        nvs->has_domain_id = true;
        nvs->domain_id = domain;
    }
    log_unreadable(NET_KEY_DOMAIN_ID, "a u8", err);
    nvs_close(handle);
}

static const net_candidate_t KCONFIG = {
    .ssid = CONFIG_ESPDOCK_WIFI_SSID,
    .password = CONFIG_ESPDOCK_WIFI_PASSWORD,
    .agent_host = CONFIG_ESPDOCK_AGENT_IP,
    .has_agent_port = true,
    .agent_port = CONFIG_ESPDOCK_AGENT_PORT,
    .has_domain_id = true,
    .domain_id = CONFIG_ESPDOCK_ROS_DOMAIN_ID,
};

static bool erase_repairs(int err)
{
    return err == ESP_ERR_NVS_NO_FREE_PAGES || err == ESP_ERR_NVS_NEW_VERSION_FOUND;
}

static void on_erase(int err)
{
    /* The partition is unusable as it is; erasing it also drops any provisioning,
     * which the log says, rather than leaving the board without Wi-Fi calibration. */
    ESP_LOGE(TAG, "NVS partition unusable (%s): erasing it; provision the board again", esp_err_to_name(err));
}

esp_err_t espdock_nvs_init(void)
{
    static const net_nvs_ops_t ops = {
        .init = nvs_flash_init,
        .erase = nvs_flash_erase,
        .erase_repairs = erase_repairs,
        .on_erase = on_erase,
    };
    static bool ready;
    return net_nvs_ready(&ops, &ready);
}

void espdock_net_load(net_settings_t *out)
{
#if CONFIG_ESPDOCK_TRANSPORT_SERIAL
    espdock_transport_serial_settings(out);
    return;
#endif
    esp_err_t err = espdock_nvs_init();
    if (err != ESP_OK) {
        ESP_LOGE(TAG, "NVS unavailable (%s): using the build's settings only", esp_err_to_name(err));
    }
    for (;;) {
        net_candidate_t nvs;
        nvs_strings_t strings;
        if (err == ESP_OK) {
            read_nvs(&nvs, &strings);
        } else {
            memset(&nvs, 0, sizeof nvs);
        }
        uint32_t problems = net_settings_choose(&nvs, &KCONFIG, out);
        if (problems == 0) {
            ESP_LOGI(TAG, "Wi-Fi \"%s\" (%s), password %s (%s)", out->ssid, net_source_name(out->ssid_from),
                     out->password[0] != '\0' ? "set" : "empty: open network",
                     net_source_name(out->password_from));
            ESP_LOGI(TAG, "agent %s (%s):%u (%s), ROS domain %u (%s)", out->agent_host,
                     net_source_name(out->agent_host_from), (unsigned)out->agent_port,
                     net_source_name(out->agent_port_from), (unsigned)out->domain_id,
                     net_source_name(out->domain_id_from));
            return;
        }
        char text[200];
        ESP_LOGE(TAG, "network settings unusable: %s", net_describe_problems(problems, text, sizeof text));
        ESP_LOGE(TAG, "provision the board: espdock provision <package> --port <port> "
                      "--wifi-ssid <ssid> --agent <ipv4>:<port>; checking again in %u s",
                 RETRY_MS / 1000u);
        vTaskDelay(pdMS_TO_TICKS(RETRY_MS));
    }
}
