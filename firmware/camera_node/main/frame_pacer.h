/*
 * Frame pacing for the camera publisher (hardware-free, host-tested).
 *
 * The publish timer ticks faster than the frame rate; the pacer decides on
 * which ticks a frame goes out. It keeps a fixed schedule (no drift when a
 * tick is late) but never bursts to catch up after a stall, so the rate can
 * never exceed the configured cap, which itself is at most 30 fps.
 */
#ifndef FRAME_PACER_H
#define FRAME_PACER_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FRAME_PACER_MAX_FPS 30u

typedef struct {
    int64_t interval_ns;
    int64_t next_due_ns;
    bool started;
} frame_pacer_t;

/** Sets the cap to fps frames per second, clamped to 1..FRAME_PACER_MAX_FPS. */
void frame_pacer_init(frame_pacer_t *pacer, uint32_t fps);

/** True when a frame may be published at now_ns (monotonic); consumes the slot. */
bool frame_pacer_should_publish(frame_pacer_t *pacer, int64_t now_ns);

#ifdef __cplusplus
}
#endif

#endif /* FRAME_PACER_H */
