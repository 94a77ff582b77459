/* The board's link to the micro-ROS agent; see espdock_transport.h and serial_link.h. */
#include "espdock_transport.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include <rmw_microros/rmw_microros.h>
#include <rmw_microxrcedds_c/config.h>

#include "esp_log.h"
#include "sdkconfig.h"

static const char *TAG = "espdock_transport";

#if CONFIG_ESPDOCK_TRANSPORT_UDP

#include "espdock_wifi.h"

#ifndef RMW_UXRCE_TRANSPORT_UDP
/* espdock builds the library for the transport the package's sdkconfig.defaults choose: a choice
   changed in menuconfig alone reaches only the app. */
#error "espdock transport is UDP but this micro-ROS library was not built with RMW_UXRCE_TRANSPORT=udp: choose the transport in sdkconfig.defaults (CONFIG_ESPDOCK_TRANSPORT_UDP=y), not in menuconfig"
#endif

bool espdock_transport_configure(rmw_init_options_t *rmw_options, const char *agent_ip, uint16_t agent_port)
{
    char port[8];
    snprintf(port, sizeof port, "%u", (unsigned)agent_port);
    return rmw_uros_options_set_udp_address(agent_ip, port, rmw_options) == RMW_RET_OK;
}

bool espdock_transport_is_up(void)
{
    return espdock_wifi_is_connected();
}

const char *espdock_transport_name(void)
{
    return "udp";
}

void espdock_transport_serial_settings(net_settings_t *out)
{
    (void)out;
    ESP_LOGE(TAG, "not a serial build");
}

#else /* serial: a UART or USB-Serial-JTAG */

#include "esp_timer.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "serial_link.h"

#ifndef RMW_UXRCE_TRANSPORT_CUSTOM
#error "espdock transport is serial but this micro-ROS library was not built with RMW_UXRCE_TRANSPORT=custom: choose the transport in sdkconfig.defaults (CONFIG_ESPDOCK_TRANSPORT_UART=y or _USB_SERIAL_JTAG=y), not in menuconfig"
#endif

/* The driver's buffers: one XRCE frame (MTU 512 by default) with room for escaping. */
#define SERIAL_BUFFER_BYTES 1024
/* Past this, a write counts as failed: on USB the host is not reading (cable out, port closed). */
#define SERIAL_WRITE_TIMEOUT_MS 100

static serial_link_t s_link;

static TickType_t ticks(uint32_t ms)
{
    TickType_t t = pdMS_TO_TICKS(ms);
    return ms > 0 && t == 0 ? 1 : t;
}

static int64_t hw_now_ms(void *hw)
{
    (void)hw;
    return esp_timer_get_time() / 1000;
}

#if CONFIG_ESPDOCK_TRANSPORT_UART

#include "driver/uart.h"

#if CONFIG_ESPDOCK_UART_PORT >= CONFIG_SOC_UART_HP_NUM
#error "CONFIG_ESPDOCK_UART_PORT names a UART this chip does not have"
#endif
#define LINK_PORT ((uart_port_t)CONFIG_ESPDOCK_UART_PORT)
#if defined(CONFIG_ESP_CONSOLE_UART_NUM) && CONFIG_ESP_CONSOLE_UART_NUM == CONFIG_ESPDOCK_UART_PORT
#define LINK_SHARES_CONSOLE 1
#else
#define LINK_SHARES_CONSOLE 0
#endif

static bool hw_install(void *hw)
{
    (void)hw;
    const uart_config_t config = {
        .baud_rate = CONFIG_ESPDOCK_UART_BAUD,
        .data_bits = UART_DATA_8_BITS,
        .parity = UART_PARITY_DISABLE,
        .stop_bits = UART_STOP_BITS_1,
        .flow_ctrl = UART_HW_FLOWCTRL_DISABLE,
        .source_clk = UART_SCLK_DEFAULT,
    };
    if (uart_is_driver_installed(LINK_PORT)) {
        return true;
    }
    esp_err_t err = uart_driver_install(LINK_PORT, SERIAL_BUFFER_BYTES, SERIAL_BUFFER_BYTES, 0, NULL, 0);
    if (err == ESP_OK) {
        err = uart_param_config(LINK_PORT, &config);
    }
    if (err == ESP_OK) {
        /* -1 is UART_PIN_NO_CHANGE: the port's default pins (UART0: the board's USB bridge). */
        err = uart_set_pin(LINK_PORT, CONFIG_ESPDOCK_UART_TX_PIN, CONFIG_ESPDOCK_UART_RX_PIN, UART_PIN_NO_CHANGE,
                           UART_PIN_NO_CHANGE);
    }
    if (err != ESP_OK) {
        ESP_LOGE(TAG, "UART%d: %s", (int)LINK_PORT, esp_err_to_name(err));
        (void)uart_driver_delete(LINK_PORT);
        return false;
    }
    return true;
}

static int hw_write(void *hw, const uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    (void)hw;
    (void)timeout_ms;
    /* Into the TX ring buffer: a UART sends whether or not anyone listens, so it never stalls long. */
    return uart_write_bytes(LINK_PORT, buf, len);
}

static int hw_read(void *hw, uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    (void)hw;
    return uart_read_bytes(LINK_PORT, buf, (uint32_t)len, ticks(timeout_ms));
}

static void hw_discard(void *hw)
{
    (void)hw;
    (void)uart_flush_input(LINK_PORT);
}

#define HW_ATTACHED NULL    /* a UART cannot tell whether anyone listens */

#elif CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG

#if !CONFIG_SOC_USB_SERIAL_JTAG_SUPPORTED
#error "this chip has no USB-Serial-JTAG port (esp32c3 and esp32s3 have one): use ESPDOCK_TRANSPORT_UART"
#endif

#include "driver/usb_serial_jtag.h"

#if defined(CONFIG_ESP_CONSOLE_USB_SERIAL_JTAG) || defined(CONFIG_ESP_CONSOLE_SECONDARY_USB_SERIAL_JTAG)
#define LINK_SHARES_CONSOLE 1
#else
#define LINK_SHARES_CONSOLE 0
#endif

static bool hw_install(void *hw)
{
    (void)hw;
    if (usb_serial_jtag_is_driver_installed()) {
        return true;
    }
    usb_serial_jtag_driver_config_t config = {
        .tx_buffer_size = SERIAL_BUFFER_BYTES,
        .rx_buffer_size = SERIAL_BUFFER_BYTES,
    };
    esp_err_t err = usb_serial_jtag_driver_install(&config);
    if (err != ESP_OK) {
        ESP_LOGE(TAG, "USB-Serial-JTAG: %s", esp_err_to_name(err));
        return false;
    }
    return true;
}

static int hw_write(void *hw, const uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    (void)hw;
    return usb_serial_jtag_write_bytes(buf, len, ticks(timeout_ms));
}

static int hw_read(void *hw, uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    (void)hw;
    return usb_serial_jtag_read_bytes(buf, (uint32_t)len, ticks(timeout_ms));
}

static void hw_discard(void *hw)
{
    (void)hw;
    uint8_t sink[64];
    while (usb_serial_jtag_read_bytes(sink, sizeof sink, 0) > 0) {
    }
}

static bool hw_attached(void *hw)
{
    (void)hw;
    /* The host's start-of-frame packets: they stop when the cable is pulled. */
    return usb_serial_jtag_is_connected();
}

#define HW_ATTACHED hw_attached

#else
#error "unknown espdock transport"
#endif

static bool xrce_open(struct uxrCustomTransport *transport)
{
    return serial_link_open(transport->args);
}

static bool xrce_close(struct uxrCustomTransport *transport)
{
    return serial_link_close(transport->args);
}

static size_t xrce_write(struct uxrCustomTransport *transport, const uint8_t *buf, size_t len, uint8_t *err)
{
    return serial_link_write(transport->args, buf, len, err);
}

static size_t xrce_read(struct uxrCustomTransport *transport, uint8_t *buf, size_t len, int timeout, uint8_t *err)
{
    return serial_link_read(transport->args, buf, len, timeout, err);
}

#if LINK_SHARES_CONSOLE
static int discard_log(const char *format, va_list args)
{
    (void)format;
    (void)args;
    return 0;
}
#endif

bool espdock_transport_configure(rmw_init_options_t *rmw_options, const char *agent_ip, uint16_t agent_port)
{
    (void)agent_ip;
    (void)agent_port;
    const serial_link_ops_t ops = {
        .install = hw_install,
        .write = hw_write,
        .read = hw_read,
        .discard_input = hw_discard,
        .attached = HW_ATTACHED,
        .now_ms = hw_now_ms,
        .hw = NULL,
        .write_timeout_ms = SERIAL_WRITE_TIMEOUT_MS,
    };
    serial_link_init(&s_link, &ops);
#if LINK_SHARES_CONSOLE
    /* Log lines written mid-frame would cost frames; the agent's side is the place to look. */
    ESP_LOGW(TAG, "the %s link is also the console: logging stops here", espdock_transport_name());
    (void)esp_log_set_vprintf(discard_log);
#endif
    /* framing=true: XRCE's stream framing (flags, escaping, CRC), what `micro_ros_agent serial` expects. */
    return rmw_uros_options_set_custom_transport(MICROROS_TRANSPORTS_FRAMING_MODE, &s_link, xrce_open, xrce_close,
                                                 xrce_write, xrce_read, rmw_options) == RMW_RET_OK;
}

bool espdock_transport_is_up(void)
{
    return s_link.ops.install != NULL && serial_link_attached(&s_link);
}

const char *espdock_transport_name(void)
{
#if CONFIG_ESPDOCK_TRANSPORT_UART
    return "uart";
#else
    return "usb-serial-jtag";
#endif
}

void espdock_transport_serial_settings(net_settings_t *out)
{
    memset(out, 0, sizeof *out);
    out->domain_id = (uint8_t)CONFIG_ESPDOCK_ROS_DOMAIN_ID;
    out->domain_id_from = NET_FROM_KCONFIG;
    ESP_LOGI(TAG, "agent over %s (no Wi-Fi, nothing to provision), ROS domain %u (build)",
             espdock_transport_name(), (unsigned)out->domain_id);
}

#endif /* CONFIG_ESPDOCK_TRANSPORT_UDP */
