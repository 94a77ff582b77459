/*
 * Reconnection state machine for a micro-ROS client (hardware-free, host-tested).
 *
 * micro-ROS does not reconnect by itself: once the agent restarts, every XRCE
 * entity on the board is gone and the board would need a reset
 * (micro_ros_espidf_component issue #181). This follows the upstream
 * reconnection pattern: ping the agent while waiting, create the entities
 * when it answers, keep pinging while connected, and on loss destroy
 * everything and start waiting again.
 *
 * All side effects go through callbacks so the machine runs unchanged on the
 * host under test and on the ESP32 against rmw_uros_ping_agent().
 */
#ifndef AGENT_LINK_H
#define AGENT_LINK_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum {
    AGENT_LINK_WAITING = 0,     /* no session; probing for the agent */
    AGENT_LINK_AVAILABLE,       /* the agent answered; entities not created yet */
    AGENT_LINK_CONNECTED,       /* session and entities up; executor spinning */
    AGENT_LINK_DISCONNECTED,    /* the agent stopped answering; entities to destroy */
} agent_link_state_t;

typedef struct {
    /* True when the agent answers. in_session tells whether a session exists:
     * without one the ping must go to the configured agent address. */
    bool (*ping)(void *ctx, bool in_session);
    /* Creates session, node and every entity; true only if all succeeded. */
    bool (*create_entities)(void *ctx);
    /* Destroys whatever create_entities made, including a partial set. */
    void (*destroy_entities)(void *ctx);
    /* Processes pending work (executor spin) while connected. */
    void (*spin)(void *ctx);
    /* Optional: told about every state change (for logs or a status LED). */
    void (*on_change)(void *ctx, agent_link_state_t from, agent_link_state_t to);
    void *ctx;
    uint32_t waiting_ping_period_ms;    /* upstream example: 500 */
    uint32_t connected_ping_period_ms;  /* upstream example: 200 */
    uint32_t missed_pings_to_drop;      /* consecutive failed pings that mean "lost"; >= 1 */
} agent_link_ops_t;

typedef struct {
    agent_link_ops_t ops;
    agent_link_state_t state;
    int64_t next_ping_ms;
    uint32_t missed_pings;
    uint32_t sessions;          /* times CONNECTED was entered */
} agent_link_t;

/** Starts the machine in WAITING with a ping due at once. */
void agent_link_init(agent_link_t *link, const agent_link_ops_t *ops, int64_t now_ms);

/** Runs one step at time now_ms (monotonic milliseconds) and returns the new state. */
agent_link_state_t agent_link_step(agent_link_t *link, int64_t now_ms);

/** Short upper-case name of a state, for logs. */
const char *agent_link_state_name(agent_link_state_t state);

#ifdef __cplusplus
}
#endif

#endif /* AGENT_LINK_H */
