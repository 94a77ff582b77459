/*
 * micro-ROS session glue shared by the espdock apps: agent address, pinging,
 * session and node lifetime, agent-synchronised time, and the loop that
 * drives the reconnection state machine (agent_link.h).
 */
#ifndef ESPDOCK_UROS_H
#define ESPDOCK_UROS_H

#include <stdbool.h>
#include <stdint.h>

#include <builtin_interfaces/msg/time.h>
#include <rcl/error_handling.h>
#include <rcl/rcl.h>
#include <rclc/rclc.h>

#include "agent_link.h"
#include "esp_log.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Error checks for rcl/rmw calls. They log the call and its location and,
 * instead of the upstream examples' vTaskDelete/abort, make the enclosing
 * function return false: a failed entity creation then sends the
 * reconnection loop back to WAITING, which tears down and retries.
 * The caller must define `static const char *TAG`.
 */
#define ESPDOCK_RC_CHECK(expr)                                                    \
    do {                                                                          \
        rcl_ret_t espdock_rc_ = (rcl_ret_t)(expr);                                \
        if (espdock_rc_ != RCL_RET_OK) {                                          \
            ESP_LOGE(TAG, "%s failed (%d) at %s:%d", #expr, (int)espdock_rc_,     \
                     __FILE__, __LINE__);                                         \
            rcl_reset_error();                                                    \
            return false;                                                         \
        }                                                                         \
    } while (0)

/* Same, but only logs: for calls whose failure leaves the node usable (a publish). */
#define ESPDOCK_RC_SOFTCHECK(expr)                                                \
    do {                                                                          \
        rcl_ret_t espdock_rc_ = (rcl_ret_t)(expr);                                \
        if (espdock_rc_ != RCL_RET_OK) {                                          \
            ESP_LOGW(TAG, "%s failed (%d) at %s:%d", #expr, (int)espdock_rc_,     \
                     __FILE__, __LINE__);                                         \
            rcl_reset_error();                                                    \
        }                                                                         \
    } while (0)

/* Reconnection timing: upstream's 500 ms / 200 ms pattern, 100 ms per ping.
 * Three missed pings, not one, drop the session: a single lost UDP datagram
 * on Wi-Fi is common and rebuilding every entity for it is expensive. */
#define ESPDOCK_UROS_WAITING_PING_MS 500u
#define ESPDOCK_UROS_CONNECTED_PING_MS 200u
#define ESPDOCK_UROS_MISSED_PINGS_TO_DROP 3u

typedef struct {
    const char *agent_ip;
    uint16_t agent_port;
    uint32_t domain_id;
    const char *node_name;
    const char *node_namespace;
} espdock_uros_config_t;

typedef struct {
    rcl_allocator_t allocator;
    rcl_init_options_t init_options;    /* kept: pings without a session need the address */
    rclc_support_t support;
    rcl_node_t node;
    const char *node_name;
    const char *node_namespace;
    int64_t last_sync_attempt_ms;
    bool clock_synced;
} espdock_uros_t;

/** Stores the agent UDP address and domain in init options used by every later session. */
bool espdock_uros_setup(espdock_uros_t *uros, const espdock_uros_config_t *config);

/** Pings the agent: through the session if in_session, else at the configured address. */
bool espdock_uros_ping(espdock_uros_t *uros, bool in_session);

/** Opens a session, creates the node and synchronises the clock with the agent. */
bool espdock_uros_open(espdock_uros_t *uros);

/** Call before destroying entities: deletions go out without waiting for a lost agent. */
void espdock_uros_begin_teardown(espdock_uros_t *uros);

/** Destroys the node and the session; safe after a partial espdock_uros_open. */
void espdock_uros_close(espdock_uros_t *uros);

/** Re-synchronises the clock periodically (more often while unsynchronised); call while connected. */
void espdock_uros_keep_clock(espdock_uros_t *uros);

/** Fills a ROS time stamp from the agent-synchronised clock (boot time if never synchronised). */
void espdock_uros_stamp(builtin_interfaces__msg__Time *stamp);

/** Monotonic milliseconds since boot, the time base of agent_link. */
int64_t espdock_uros_now_ms(void);

/** Steps the reconnection state machine forever, yielding step_delay_ms between steps. */
void espdock_uros_run(agent_link_t *link, uint32_t step_delay_ms);

/** An app's part of a micro-ROS node: its entities, and its work while connected. */
typedef struct {
    bool (*create_entities)(void *ctx);   /* on espdock_uros_t's node; false: tear down and retry */
    void (*destroy_entities)(void *ctx);  /* must cope with a partial create */
    void (*spin)(void *ctx);
    void *ctx;
} espdock_uros_app_t;

/**
 * Task body shared by the apps: sets micro-ROS up with config, then runs the agent
 * reconnection loop for app forever. Deletes the calling task if config is invalid.
 */
void espdock_uros_serve(espdock_uros_t *uros, const espdock_uros_config_t *config, espdock_uros_app_t app,
                        uint32_t step_delay_ms);

#ifdef __cplusplus
}
#endif

#endif /* ESPDOCK_UROS_H */
