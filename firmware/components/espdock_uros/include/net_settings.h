/*
 * Where a board's network settings come from, and whether they are usable.
 *
 * `espdock provision` writes the Wi-Fi credentials, the agent address and the
 * ROS domain into the NVS namespace "espdock"; the app's Kconfig options are
 * the fallback for whatever NVS lacks (their defaults are empty, so a build
 * carries no network secrets unless someone puts them there). This file is
 * plain C with no ESP-IDF includes, so the choice and the checks are tested
 * on the host; espdock_net.c does the NVS reading and the logging.
 */
#ifndef NET_SETTINGS_H
#define NET_SETTINGS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NET_SSID_MAX 32         /* bytes: the 802.11 limit and the driver's buffer */
#define NET_PASSWORD_MIN 8      /* WPA2 passphrase, printable ASCII */
#define NET_PASSWORD_MAX 63
#define NET_HOST_MAX 15         /* "255.255.255.255" */
#define NET_DOMAIN_ID_MAX 232   /* the largest ROS_DOMAIN_ID DDS maps to valid ports */

/* NVS keys in the "espdock" namespace; espdock's provisioning writes the same. */
#define NET_NVS_NAMESPACE "espdock"
#define NET_KEY_SSID "ssid"
#define NET_KEY_PASSWORD "password"
#define NET_KEY_AGENT_HOST "agent_host"
#define NET_KEY_AGENT_PORT "agent_port"
#define NET_KEY_DOMAIN_ID "domain_id"

typedef enum {
    NET_FROM_NONE = 0,
    NET_FROM_NVS,
    NET_FROM_KCONFIG,
} net_source_t;

/* One source's values; NULL strings and has_* false mean "this source has no value". */
typedef struct {
    const char *ssid;
    const char *password;
    const char *agent_host;
    bool has_agent_port;
    uint32_t agent_port;
    bool has_domain_id;
    uint32_t domain_id;
} net_candidate_t;

typedef struct {
    char ssid[NET_SSID_MAX + 1];
    char password[NET_PASSWORD_MAX + 1];
    char agent_host[NET_HOST_MAX + 1];
    uint16_t agent_port;
    uint8_t domain_id;
    net_source_t ssid_from;
    net_source_t password_from;
    net_source_t agent_host_from;
    net_source_t agent_port_from;
    net_source_t domain_id_from;
} net_settings_t;

/* Problems found by net_settings_choose, as bits. */
enum {
    NET_MISSING_SSID = 1u << 0,
    NET_MISSING_AGENT_HOST = 1u << 1,
    NET_MISSING_AGENT_PORT = 1u << 2,
    NET_BAD_SSID = 1u << 3,
    NET_BAD_PASSWORD = 1u << 4,
    NET_BAD_AGENT_HOST = 1u << 5,
    NET_BAD_AGENT_PORT = 1u << 6,
    NET_BAD_DOMAIN_ID = 1u << 7,
};

/*
 * Fills OUT from NVS where it has a value, else from KCONFIG (an empty Kconfig
 * string counts as no value). The password always comes from wherever the SSID
 * came from: credentials are a pair, and an NVS SSID with no NVS password is an
 * open network, not one with the build's password. A missing domain id is 0.
 * Returns 0 when OUT is usable, else the NET_* bits of what is missing or wrong.
 */
uint32_t net_settings_choose(const net_candidate_t *nvs, const net_candidate_t *kconfig, net_settings_t *out);

/* True for a dotted-quad IPv4 address (four decimal parts 0..255, no leading zeros, not 0.0.0.0). */
bool net_is_ipv4(const char *text);

/* Writes a one-line English description of PROBLEMS into BUF; returns BUF. */
const char *net_describe_problems(uint32_t problems, char *buf, size_t size);

const char *net_source_name(net_source_t source);

/*
 * True when the micro-ROS library keeps every digit of agent port PORT. rmw_microxrcedds copies
 * the port into char[MAX_PORT_LEN] with snprintf(.., MAX_PORT_LEN, ..), so it keeps
 * MAX_PORT_LEN - 1 digits: 4 before micro-ROS/rmw_microxrcedds#315 (MAX_PORT_LEN 5, ports of
 * 10000 and up cut to port/10) and 5 after it (MAX_PORT_LEN 6). Pass the library's MAX_PORT_LEN.
 */
bool net_agent_port_fits(uint32_t port, uint32_t max_port_len);

/* nvs_flash_init and what repairs it, as espdock_net.c passes them (host-tested without IDF). */
typedef struct {
    int (*init)(void);               /* nvs_flash_init (esp_err_t is int) */
    int (*erase)(void);              /* nvs_flash_erase */
    bool (*erase_repairs)(int err);  /* no free pages, new version found */
    void (*on_erase)(int err);       /* logs that provisioning is lost */
} net_nvs_ops_t;

/*
 * Initialises NVS (erasing an unusable partition once per attempt) until an attempt succeeds:
 * then *READY is set and later calls return 0 at once. A failed attempt is made again on the
 * next call, so a caller that retries (Wi-Fi start) retries NVS too. Returns 0 or the error.
 */
int net_nvs_ready(const net_nvs_ops_t *ops, bool *ready);

#ifdef __cplusplus
}
#endif

#endif /* NET_SETTINGS_H */
