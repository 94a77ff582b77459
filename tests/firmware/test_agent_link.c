/* Host tests for firmware/components/espdock_uros/agent_link.c with a scripted fake agent. */
#include <string.h>

#include "agent_link.h"
#include "testkit.h"

#define MAX_TRANSITIONS 64

/* Fake agent and entity layer: answers pings from a switch, counts calls. */
typedef struct {
    bool agent_up;
    int create_failures_left;   /* next create_entities calls that fail */
    int pings_no_session;
    int pings_in_session;
    int creates;
    int destroys;
    int spins;
    bool entities_alive;        /* true between a successful create and a destroy */
    int spins_without_entities;
    agent_link_state_t from[MAX_TRANSITIONS];
    agent_link_state_t to[MAX_TRANSITIONS];
    int transitions;
} fake_t;

static bool fake_ping(void *ctx, bool in_session)
{
    fake_t *f = ctx;
    if (in_session) {
        f->pings_in_session++;
    } else {
        f->pings_no_session++;
    }
    return f->agent_up;
}

static bool fake_create(void *ctx)
{
    fake_t *f = ctx;
    f->creates++;
    if (f->create_failures_left > 0) {
        f->create_failures_left--;
        return false;
    }
    f->entities_alive = true;
    return true;
}

static void fake_destroy(void *ctx)
{
    fake_t *f = ctx;
    f->destroys++;
    f->entities_alive = false;
}

static void fake_spin(void *ctx)
{
    fake_t *f = ctx;
    f->spins++;
    if (!f->entities_alive) {
        f->spins_without_entities++;
    }
}

static void fake_on_change(void *ctx, agent_link_state_t from, agent_link_state_t to)
{
    fake_t *f = ctx;
    if (f->transitions < MAX_TRANSITIONS) {
        f->from[f->transitions] = from;
        f->to[f->transitions] = to;
    }
    f->transitions++;
}

static agent_link_ops_t fake_ops(fake_t *f, uint32_t missed_to_drop)
{
    agent_link_ops_t ops = {
        .ping = fake_ping,
        .create_entities = fake_create,
        .destroy_entities = fake_destroy,
        .spin = fake_spin,
        .on_change = fake_on_change,
        .ctx = f,
        .waiting_ping_period_ms = 500,
        .connected_ping_period_ms = 200,
        .missed_pings_to_drop = missed_to_drop,
    };
    return ops;
}

/* Steps every 10 ms of simulated time until `until_ms`. */
static int64_t run_until(agent_link_t *link, int64_t now_ms, int64_t until_ms)
{
    for (; now_ms < until_ms; now_ms += 10) {
        agent_link_step(link, now_ms);
    }
    return now_ms;
}

static void test_starts_waiting_and_pings_at_once(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    agent_link_ops_t ops = fake_ops(&f, 1);
    agent_link_t link;
    agent_link_init(&link, &ops, 1000);
    TK_CHECK(link.state == AGENT_LINK_WAITING, "initial state");
    TK_CHECK(agent_link_step(&link, 1000) == AGENT_LINK_WAITING, "agent down: still waiting");
    TK_CHECK_EQ_INT(f.pings_no_session, 1, "first ping immediate");
    agent_link_step(&link, 1490);
    TK_CHECK_EQ_INT(f.pings_no_session, 1, "no ping before the waiting period");
    agent_link_step(&link, 1500);
    TK_CHECK_EQ_INT(f.pings_no_session, 2, "ping after 500 ms");
    TK_CHECK_EQ_INT(f.creates, 0, "nothing created while the agent is down");
    TK_CHECK_EQ_INT(f.spins, 0, "no spinning while waiting");
}

static void test_full_disconnect_reconnect_cycle(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    agent_link_ops_t ops = fake_ops(&f, 1);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);

    /* Board boots before the agent. */
    int64_t now = run_until(&link, 0, 2000);
    TK_CHECK(link.state == AGENT_LINK_WAITING, "waiting without agent");
    TK_CHECK_EQ_INT(f.pings_no_session, 4, "pings at 0, 500, 1000, 1500");

    /* Agent comes up: waiting -> available -> connected. */
    f.agent_up = true;
    TK_CHECK(agent_link_step(&link, now) == AGENT_LINK_AVAILABLE, "ping answered -> AVAILABLE");
    TK_CHECK_EQ_INT(f.creates, 0, "entities are created in the next step");
    TK_CHECK(agent_link_step(&link, now + 10) == AGENT_LINK_CONNECTED, "created -> CONNECTED");
    TK_CHECK_EQ_INT(f.creates, 1, "created once");
    TK_CHECK_EQ_INT(link.sessions, 1, "one session");
    now = run_until(&link, now + 20, now + 1020);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "stays connected while the agent answers");
    TK_CHECK(f.spins >= 95, "executor spun on every connected step (%d)", f.spins);
    TK_CHECK(f.pings_in_session >= 4 && f.pings_in_session <= 6, "session pings every 200 ms (%d)",
             f.pings_in_session);
    TK_CHECK_EQ_INT(f.creates, 1, "no re-creation while connected");
    TK_CHECK_EQ_INT(f.destroys, 0, "nothing destroyed while connected");

    /* Agent restarts: connected -> disconnected -> waiting. */
    f.agent_up = false;
    int spins_before = f.spins;
    while (link.state == AGENT_LINK_CONNECTED) {
        agent_link_step(&link, now);
        now += 10;
    }
    TK_CHECK(link.state == AGENT_LINK_DISCONNECTED, "lost ping -> DISCONNECTED");
    TK_CHECK(f.spins - spins_before <= 20, "stopped spinning within one ping period");
    TK_CHECK_EQ_INT(f.destroys, 0, "destroyed in the DISCONNECTED step, not before");
    TK_CHECK(agent_link_step(&link, now) == AGENT_LINK_WAITING, "DISCONNECTED -> WAITING");
    TK_CHECK_EQ_INT(f.destroys, 1, "entities destroyed once");
    TK_CHECK(!f.entities_alive, "no entities left");
    int spins_at_loss = f.spins;
    now = run_until(&link, now + 10, now + 3000);
    TK_CHECK(link.state == AGENT_LINK_WAITING, "waiting while the agent is down");
    TK_CHECK_EQ_INT(f.spins, spins_at_loss, "no spinning without a session");
    TK_CHECK_EQ_INT(f.creates, 1, "no creation attempts while the agent is down");

    /* Agent back: waiting -> available -> connected, without a board reset. */
    f.agent_up = true;
    now = run_until(&link, now, now + 600);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "reconnected");
    TK_CHECK_EQ_INT(f.creates, 2, "entities created twice in total");
    TK_CHECK_EQ_INT(f.destroys, 1, "destroyed once in total");
    TK_CHECK_EQ_INT(link.sessions, 2, "two sessions");
    TK_CHECK_EQ_INT(f.spins_without_entities, 0, "never spun without entities");

    static const agent_link_state_t expected[][2] = {
        {AGENT_LINK_WAITING, AGENT_LINK_AVAILABLE},
        {AGENT_LINK_AVAILABLE, AGENT_LINK_CONNECTED},
        {AGENT_LINK_CONNECTED, AGENT_LINK_DISCONNECTED},
        {AGENT_LINK_DISCONNECTED, AGENT_LINK_WAITING},
        {AGENT_LINK_WAITING, AGENT_LINK_AVAILABLE},
        {AGENT_LINK_AVAILABLE, AGENT_LINK_CONNECTED},
    };
    TK_CHECK_EQ_INT(f.transitions, 6, "transition count");
    for (int i = 0; i < 6 && i < f.transitions; i++) {
        TK_CHECK(f.from[i] == expected[i][0] && f.to[i] == expected[i][1], "transition %d: %s -> %s", i,
                 agent_link_state_name(f.from[i]), agent_link_state_name(f.to[i]));
    }
}

static void test_failed_creation_is_cleaned_up_and_retried(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    f.agent_up = true;
    f.create_failures_left = 2;
    agent_link_ops_t ops = fake_ops(&f, 1);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    TK_CHECK(agent_link_step(&link, 0) == AGENT_LINK_AVAILABLE, "agent answers");
    TK_CHECK(agent_link_step(&link, 10) == AGENT_LINK_WAITING, "failed creation -> WAITING");
    TK_CHECK_EQ_INT(f.destroys, 1, "partial entities destroyed");
    TK_CHECK(agent_link_step(&link, 20) == AGENT_LINK_WAITING, "waits before probing again");
    TK_CHECK_EQ_INT(f.pings_no_session, 1, "no ping inside the waiting period");
    int64_t now = run_until(&link, 30, 2000);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "third creation succeeds");
    TK_CHECK_EQ_INT(f.creates, 3, "three creation attempts");
    TK_CHECK_EQ_INT(f.destroys, 2, "two cleanups for two failures");
    TK_CHECK_EQ_INT(link.sessions, 1, "one session");
    (void)now;
}

static void test_tolerates_isolated_lost_pings(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    f.agent_up = true;
    agent_link_ops_t ops = fake_ops(&f, 3);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    int64_t now = run_until(&link, 0, 100);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "connected");

    /* Two lost pings (a Wi-Fi hiccup) then an answer: the session survives. */
    f.agent_up = false;
    now = run_until(&link, now, now + 400);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "two misses tolerated");
    f.agent_up = true;
    now = run_until(&link, now, now + 400);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "recovered");
    TK_CHECK_EQ_INT(link.missed_pings, 0, "miss counter reset by an answer");

    /* Three in a row: dropped. */
    f.agent_up = false;
    now = run_until(&link, now, now + 700);
    TK_CHECK(link.state == AGENT_LINK_WAITING, "three misses drop the session");
    TK_CHECK_EQ_INT(f.destroys, 1, "destroyed once");
    TK_CHECK_EQ_INT(f.creates, 1, "created once");
}

static void test_zero_miss_threshold_means_one(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    f.agent_up = true;
    agent_link_ops_t ops = fake_ops(&f, 0);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    int64_t now = run_until(&link, 0, 100);
    f.agent_up = false;
    run_until(&link, now, now + 210);
    TK_CHECK(link.state == AGENT_LINK_DISCONNECTED || link.state == AGENT_LINK_WAITING,
             "a single miss drops the session when the threshold is 0");
}

static void test_many_agent_restarts(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    agent_link_ops_t ops = fake_ops(&f, 1);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    int64_t now = 0;
    for (int i = 0; i < 20; i++) {
        f.agent_up = true;
        now = run_until(&link, now, now + 1000);
        TK_CHECK(link.state == AGENT_LINK_CONNECTED, "cycle %d connected", i);
        f.agent_up = false;
        now = run_until(&link, now, now + 1000);
        TK_CHECK(link.state == AGENT_LINK_WAITING, "cycle %d waiting", i);
    }
    TK_CHECK_EQ_INT(f.creates, 20, "one creation per agent start");
    TK_CHECK_EQ_INT(f.destroys, 20, "one destruction per agent stop");
    TK_CHECK_EQ_INT(link.sessions, 20, "20 sessions");
    TK_CHECK_EQ_INT(f.spins_without_entities, 0, "never spun without entities");
}

static void test_corrupt_state_recovers(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    f.agent_up = true;
    agent_link_ops_t ops = fake_ops(&f, 1);
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    link.state = (agent_link_state_t)42;
    TK_CHECK(agent_link_step(&link, 0) == AGENT_LINK_DISCONNECTED, "unknown state -> DISCONNECTED");
    TK_CHECK(agent_link_step(&link, 10) == AGENT_LINK_WAITING, "then cleaned up");
    TK_CHECK_EQ_INT(f.destroys, 1, "cleanup ran");
}

static void test_optional_on_change_and_names(void)
{
    fake_t f;
    memset(&f, 0, sizeof f);
    f.agent_up = true;
    agent_link_ops_t ops = fake_ops(&f, 1);
    ops.on_change = NULL;
    agent_link_t link;
    agent_link_init(&link, &ops, 0);
    run_until(&link, 0, 100);
    TK_CHECK(link.state == AGENT_LINK_CONNECTED, "works without on_change");
    TK_CHECK(strcmp(agent_link_state_name(AGENT_LINK_WAITING), "WAITING") == 0, "name");
    TK_CHECK(strcmp(agent_link_state_name(AGENT_LINK_AVAILABLE), "AVAILABLE") == 0, "name");
    TK_CHECK(strcmp(agent_link_state_name(AGENT_LINK_CONNECTED), "CONNECTED") == 0, "name");
    TK_CHECK(strcmp(agent_link_state_name(AGENT_LINK_DISCONNECTED), "DISCONNECTED") == 0, "name");
    TK_CHECK(strcmp(agent_link_state_name((agent_link_state_t)9), "UNKNOWN") == 0, "name");
}

int main(void)
{
    test_starts_waiting_and_pings_at_once();
    test_full_disconnect_reconnect_cycle();
    test_failed_creation_is_cleaned_up_and_retried();
    test_tolerates_isolated_lost_pings();
    test_zero_miss_threshold_means_one();
    test_many_agent_restarts();
    test_corrupt_state_recovers();
    test_optional_on_change_and_names();
    return tk_report("agent_link");
}
