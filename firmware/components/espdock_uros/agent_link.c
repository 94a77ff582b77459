/* Reconnection state machine; see agent_link.h. No ESP-IDF or micro-ROS includes. */
#include "agent_link.h"

#include <stddef.h>

static void enter(agent_link_t *link, agent_link_state_t to)
{
    agent_link_state_t from = link->state;
    link->state = to;
    if (from != to && link->ops.on_change != NULL) {
        link->ops.on_change(link->ops.ctx, from, to);
    }
}

static bool ping_due(const agent_link_t *link, int64_t now_ms)
{
    return now_ms >= link->next_ping_ms;
}

static void step_waiting(agent_link_t *link, int64_t now_ms)
{
    if (!ping_due(link, now_ms)) {
        return;
    }
    link->next_ping_ms = now_ms + link->ops.waiting_ping_period_ms;
    if (link->ops.ping(link->ops.ctx, false)) {
        enter(link, AGENT_LINK_AVAILABLE);
    }
}

static void step_available(agent_link_t *link, int64_t now_ms)
{
    if (link->ops.create_entities(link->ops.ctx)) {
        link->missed_pings = 0;
        link->next_ping_ms = now_ms + link->ops.connected_ping_period_ms;
        link->sessions++;
        enter(link, AGENT_LINK_CONNECTED);
        return;
    }
    /* A half-built session holds agent-side objects and board memory:
     * release it before probing again, as the upstream pattern does. */
    link->ops.destroy_entities(link->ops.ctx);
    link->next_ping_ms = now_ms + link->ops.waiting_ping_period_ms;
    enter(link, AGENT_LINK_WAITING);
}

static void step_connected(agent_link_t *link, int64_t now_ms)
{
    if (ping_due(link, now_ms)) {
        link->next_ping_ms = now_ms + link->ops.connected_ping_period_ms;
        if (link->ops.ping(link->ops.ctx, true)) {
            link->missed_pings = 0;
        } else if (++link->missed_pings >= link->ops.missed_pings_to_drop) {
            enter(link, AGENT_LINK_DISCONNECTED);
            return;
        }
    }
    link->ops.spin(link->ops.ctx);
}

static void step_disconnected(agent_link_t *link, int64_t now_ms)
{
    link->ops.destroy_entities(link->ops.ctx);
    /* Give a restarting agent a moment instead of probing it immediately. */
    link->next_ping_ms = now_ms + link->ops.waiting_ping_period_ms;
    enter(link, AGENT_LINK_WAITING);
}

void agent_link_init(agent_link_t *link, const agent_link_ops_t *ops, int64_t now_ms)
{
    link->ops = *ops;
    if (link->ops.missed_pings_to_drop == 0) {
        link->ops.missed_pings_to_drop = 1;
    }
    link->state = AGENT_LINK_WAITING;
    link->next_ping_ms = now_ms;
    link->missed_pings = 0;
    link->sessions = 0;
}

agent_link_state_t agent_link_step(agent_link_t *link, int64_t now_ms)
{
    switch (link->state) {
    case AGENT_LINK_WAITING:
        step_waiting(link, now_ms);
        break;
    case AGENT_LINK_AVAILABLE:
        step_available(link, now_ms);
        break;
    case AGENT_LINK_CONNECTED:
        step_connected(link, now_ms);
        break;
    case AGENT_LINK_DISCONNECTED:
        step_disconnected(link, now_ms);
        break;
    default:
        /* Memory corruption or a bad cast: restart from a known state. */
        enter(link, AGENT_LINK_DISCONNECTED);
        break;
    }
    return link->state;
}

const char *agent_link_state_name(agent_link_state_t state)
{
    switch (state) {
    case AGENT_LINK_WAITING:
        return "WAITING";
    case AGENT_LINK_AVAILABLE:
        return "AVAILABLE";
    case AGENT_LINK_CONNECTED:
        return "CONNECTED";
    case AGENT_LINK_DISCONNECTED:
        return "DISCONNECTED";
    default:
        return "UNKNOWN";
    }
}
