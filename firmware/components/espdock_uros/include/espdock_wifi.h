/*
 * Wi-Fi station that never gives up.
 *
 * The micro-ROS component's own network helper stops retrying after a few
 * attempts; a board that must survive an access point or agent restart
 * without a reset needs to keep reconnecting, so the apps use this instead.
 */
#ifndef ESPDOCK_WIFI_H
#define ESPDOCK_WIFI_H

#include <stdbool.h>
#include <stdint.h>

#include "esp_err.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Initialises NVS, netif and the Wi-Fi driver and starts connecting; returns without waiting. */
esp_err_t espdock_wifi_start(const char *ssid, const char *password, bool power_save);

/** espdock_wifi_start until it succeeds, backing off from 0.5 s to 30 s between attempts: a board
 *  whose Wi-Fi failed to start (NVS, memory) keeps trying instead of sitting idle. */
void espdock_wifi_start_retrying(const char *ssid, const char *password, bool power_save);

/** True while the station has an IP address. */
bool espdock_wifi_is_connected(void);

/** Blocks up to timeout_ms for an IP address; true if connected. */
bool espdock_wifi_wait_connected(uint32_t timeout_ms);

#ifdef __cplusplus
}
#endif

#endif /* ESPDOCK_WIFI_H */
