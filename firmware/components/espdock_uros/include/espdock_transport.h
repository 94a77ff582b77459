/*
 * How the board reaches the micro-ROS agent, chosen per app in Kconfig
 * (menu "espdock micro-ROS transport", set in sdkconfig.defaults): UDP over
 * Wi-Fi (the default), or a serial line to an agent started with
 * `micro_ros_agent serial --dev <device> -b <baud>` on a UART or the chip's
 * USB-Serial-JTAG port. The micro-ROS library must be built to match
 * (RMW_UXRCE_TRANSPORT=udp or custom); espdock builds it so from the same
 * setting, and a mismatched library fails the build here.
 */
#ifndef ESPDOCK_TRANSPORT_H
#define ESPDOCK_TRANSPORT_H

#include <stdbool.h>
#include <stdint.h>

#include <rmw/init_options.h>

#include "net_settings.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Points RMW_OPTIONS at the agent: the UDP address, or the serial custom transport. */
bool espdock_transport_configure(rmw_init_options_t *rmw_options, const char *agent_ip, uint16_t agent_port);

/** Whether the agent can be reachable now (Wi-Fi associated; the serial host attached). */
bool espdock_transport_is_up(void);

/** The transport's name for logs: "udp", "uart" or "usb-serial-jtag". */
const char *espdock_transport_name(void);

/**
 * Settings for a board whose link is serial: no Wi-Fi and no agent address
 * to provision; the ROS domain comes from the build (ESPDOCK_ROS_DOMAIN_ID).
 */
void espdock_transport_serial_settings(net_settings_t *out);

#ifdef __cplusplus
}
#endif

#endif /* ESPDOCK_TRANSPORT_H */
