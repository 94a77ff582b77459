/* Frame pacing; see frame_pacer.h. No ESP-IDF or micro-ROS includes. */
#include "frame_pacer.h"

#define NS_PER_S 1000000000LL

void frame_pacer_init(frame_pacer_t *pacer, uint32_t fps)
{
    if (fps == 0u) {
        fps = 1u;
    }
    if (fps > FRAME_PACER_MAX_FPS) {
        fps = FRAME_PACER_MAX_FPS;
    }
    /* Round the interval up: 1e9/30 truncated would allow 30.0000003 fps. */
    pacer->interval_ns = (NS_PER_S + (int64_t)fps - 1) / (int64_t)fps;
    pacer->next_due_ns = 0;
    pacer->started = false;
}

bool frame_pacer_should_publish(frame_pacer_t *pacer, int64_t now_ns)
{
    if (!pacer->started) {
        pacer->started = true;
        pacer->next_due_ns = now_ns + pacer->interval_ns;
        return true;
    }
    if (now_ns < pacer->next_due_ns) {
        return false;
    }
    pacer->next_due_ns += pacer->interval_ns;
    if (pacer->next_due_ns <= now_ns) {
        /* More than a whole interval behind (slow capture, blocked publish):
         * restart the schedule rather than firing back-to-back frames. */
        pacer->next_due_ns = now_ns + pacer->interval_ns;
    }
    return true;
}
