/*
 * The board's network settings at boot: NVS namespace "espdock" (written by
 * `espdock provision`) first, the app's ESPDOCK_* Kconfig options for what
 * NVS lacks. The choice itself is net_settings.c (host-tested).
 */
#ifndef ESPDOCK_NET_H
#define ESPDOCK_NET_H

#include "esp_err.h"
#include "net_settings.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Fills OUT and logs where each value came from (never the password). While
 * the settings are missing or invalid it logs what is wrong and how to
 * provision the board, and checks again every few seconds: it returns only
 * with usable settings, and never crashes the app.
 */
void espdock_net_load(net_settings_t *out);

/** nvs_flash_init until it succeeds once (Wi-Fi keeps its calibration there too); a failure is tried again
 * on the next call, so Wi-Fi's start retries retry NVS. */
esp_err_t espdock_nvs_init(void);

#ifdef __cplusplus
}
#endif

#endif /* ESPDOCK_NET_H */
