/* Host tests for firmware/camera_node/main/frame_pacer.c, against a simulated clock. */
#include "frame_pacer.h"
#include "testkit.h"

#define MS 1000000LL
#define SECOND 1000000000LL
#define MAX_EVENTS 4096

typedef struct {
    int64_t at[MAX_EVENTS];
    int count;
} publishes_t;

/* Drives the pacer with a timer ticking every tick_ns plus an optional
 * deterministic jitter, for duration_ns, and records publish times. */
static void simulate(frame_pacer_t *p, int64_t tick_ns, int64_t jitter_ns, int64_t duration_ns,
                     publishes_t *out)
{
    out->count = 0;
    unsigned seed = 12345u;
    for (int64_t t = 0; t < duration_ns; t += tick_ns) {
        seed = seed * 1103515245u + 12345u;
        int64_t jitter = jitter_ns > 0 ? (int64_t)((seed >> 8) % (unsigned)jitter_ns) : 0;
        int64_t now = t + jitter;
        if (frame_pacer_should_publish(p, now) && out->count < MAX_EVENTS) {
            out->at[out->count++] = now;
        }
    }
}

/* Largest number of publishes inside any window of window_ns. */
static int max_in_window(const publishes_t *pubs, int64_t window_ns)
{
    int best = 0;
    int start = 0;
    for (int end = 0; end < pubs->count; end++) {
        while (pubs->at[end] - pubs->at[start] >= window_ns) {
            start++;
        }
        if (end - start + 1 > best) {
            best = end - start + 1;
        }
    }
    return best;
}

static void test_interval_rounds_up(void)
{
    frame_pacer_t p;
    frame_pacer_init(&p, 30);
    TK_CHECK_EQ_INT(p.interval_ns, 33333334, "30 fps interval rounded up");
    TK_CHECK(p.interval_ns * 30 >= SECOND, "30 intervals never shorter than a second");
    frame_pacer_init(&p, 1);
    TK_CHECK_EQ_INT(p.interval_ns, SECOND, "1 fps interval");
}

static void test_fps_is_clamped(void)
{
    frame_pacer_t p;
    frame_pacer_init(&p, 1000);
    TK_CHECK_EQ_INT(p.interval_ns, 33333334, "1000 fps request capped at 30");
    frame_pacer_init(&p, 31);
    TK_CHECK_EQ_INT(p.interval_ns, 33333334, "31 fps request capped at 30");
    frame_pacer_init(&p, 0);
    TK_CHECK_EQ_INT(p.interval_ns, SECOND, "0 fps treated as 1 fps");
}

static void test_first_tick_publishes(void)
{
    frame_pacer_t p;
    frame_pacer_init(&p, 30);
    TK_CHECK(frame_pacer_should_publish(&p, 5 * SECOND), "first call publishes");
    TK_CHECK(!frame_pacer_should_publish(&p, 5 * SECOND), "same instant: no second frame");
    TK_CHECK(!frame_pacer_should_publish(&p, 5 * SECOND + 33 * MS), "33 ms later: too early");
    TK_CHECK(frame_pacer_should_publish(&p, 5 * SECOND + 34 * MS), "34 ms later: due");
}

static void test_fast_timer_caps_at_30_fps(void)
{
    static publishes_t pubs;
    const int64_t ticks[] = {1 * MS, 5 * MS, 10 * MS};
    for (unsigned i = 0; i < sizeof ticks / sizeof ticks[0]; i++) {
        frame_pacer_t p;
        frame_pacer_init(&p, 30);
        simulate(&p, ticks[i], 0, 10 * SECOND, &pubs);
        TK_CHECK(pubs.count >= 299 && pubs.count <= 301, "tick %lld ms: %d frames in 10 s",
                 (long long)(ticks[i] / MS), pubs.count);
        TK_CHECK(max_in_window(&pubs, SECOND) <= 31, "tick %lld ms: %d frames in one second",
                 (long long)(ticks[i] / MS), max_in_window(&pubs, SECOND));
    }
}

static void test_jittery_timer_still_capped(void)
{
    static publishes_t pubs;
    frame_pacer_t p;
    frame_pacer_init(&p, 30);
    simulate(&p, 10 * MS, 9 * MS, 20 * SECOND, &pubs);
    TK_CHECK(pubs.count <= 601, "%d frames in 20 s with jitter", pubs.count);
    TK_CHECK(pubs.count >= 560, "jitter should not starve the stream: %d frames", pubs.count);
    TK_CHECK(max_in_window(&pubs, SECOND) <= 31, "%d frames in one second",
             max_in_window(&pubs, SECOND));
}

static void test_lower_cap(void)
{
    static publishes_t pubs;
    frame_pacer_t p;
    frame_pacer_init(&p, 10);
    simulate(&p, 1 * MS, 0, 10 * SECOND, &pubs);
    TK_CHECK(pubs.count >= 99 && pubs.count <= 101, "10 fps cap: %d frames in 10 s", pubs.count);
}

static void test_slow_timer_no_catch_up_burst(void)
{
    static publishes_t pubs;
    frame_pacer_t p;
    frame_pacer_init(&p, 30);
    /* Capture slower than the cap: every tick publishes, never two per tick. */
    simulate(&p, 50 * MS, 0, 10 * SECOND, &pubs);
    TK_CHECK_EQ_INT(pubs.count, 200, "50 ms ticks give 20 fps");

    frame_pacer_init(&p, 30);
    TK_CHECK(frame_pacer_should_publish(&p, 0), "start");
    TK_CHECK(frame_pacer_should_publish(&p, 2 * SECOND), "after a 2 s stall");
    TK_CHECK(!frame_pacer_should_publish(&p, 2 * SECOND + 1 * MS), "no burst to make up the stall");
    TK_CHECK(!frame_pacer_should_publish(&p, 2 * SECOND + 30 * MS), "still no burst");
    TK_CHECK(frame_pacer_should_publish(&p, 2 * SECOND + 34 * MS), "next slot one interval later");
}

static void test_reinit_restarts_schedule(void)
{
    frame_pacer_t p;
    frame_pacer_init(&p, 30);
    TK_CHECK(frame_pacer_should_publish(&p, 100 * SECOND), "first");
    frame_pacer_init(&p, 30);   /* as after a reconnection */
    TK_CHECK(frame_pacer_should_publish(&p, 1 * MS), "publishes after re-init, even if clock is earlier");
}

int main(void)
{
    test_interval_rounds_up();
    test_fps_is_clamped();
    test_first_tick_publishes();
    test_fast_timer_caps_at_30_fps();
    test_jittery_timer_still_capped();
    test_lower_cap();
    test_slow_timer_no_catch_up_burst();
    test_reinit_restarts_schedule();
    return tk_report("frame_pacer");
}
