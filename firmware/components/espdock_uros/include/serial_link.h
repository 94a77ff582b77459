/*
 * A byte link to the micro-ROS agent over a serial line (a UART, or the
 * chip's USB-Serial-JTAG port), behind Micro XRCE-DDS's custom transport
 * (hardware-free, host-tested).
 *
 * It moves bytes only: XRCE's own framing (rmw_uros_set_custom_transport
 * with framing=true: flags, escaping, CRC) finds the frames, so a log line or
 * a half frame left on the wire costs one frame, not the session.
 *
 * The driver is installed once and kept: the XRCE client opens and closes the
 * transport for every ping without a session (every 500 ms while waiting),
 * and re-installing a UART or USB driver each time would drop bytes the agent
 * is sending. Opening discards what arrived while no session listened (stale
 * replies, half frames from before a cable was pulled).
 *
 * Unplugging is seen two ways: where the port can tell (USB-Serial-JTAG sees
 * the host's start-of-frame packets stop) writes fail at once; otherwise
 * writes time out. Either way the pings fail and agent_link tears the session
 * down; after the cable is back, the next ping opens a fresh link.
 */
#ifndef SERIAL_LINK_H
#define SERIAL_LINK_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    /* Installs and configures the driver; retried on the next open until it succeeds. */
    bool (*install)(void *hw);
    /* Queues up to len bytes within timeout_ms; bytes accepted, or < 0 on a driver error. */
    int (*write)(void *hw, const uint8_t *buf, size_t len, uint32_t timeout_ms);
    /* Waits up to timeout_ms for bytes; bytes read (0 on timeout), or < 0 on a driver error. */
    int (*read)(void *hw, uint8_t *buf, size_t len, uint32_t timeout_ms);
    /* Drops whatever the driver has received and not yet read. */
    void (*discard_input)(void *hw);
    /* Optional (NULL: always true): false while the host is known to be absent. */
    bool (*attached)(void *hw);
    /* Monotonic milliseconds. */
    int64_t (*now_ms)(void *hw);
    void *hw;
    /* How long one XRCE write may wait for room before it counts as failed. */
    uint32_t write_timeout_ms;
} serial_link_ops_t;

typedef struct {
    serial_link_ops_t ops;
    bool installed;
    bool open;
    bool was_attached;
    uint32_t opens;             /* successful opens (sessions and pings) */
    uint32_t reattaches;        /* times the host came back after being absent */
    uint32_t failed_writes;     /* writes that could not queue every byte */
} serial_link_t;

/** Sets LINK up with OPS; installs nothing yet. */
void serial_link_init(serial_link_t *link, const serial_link_ops_t *ops);

/** XRCE open: installs the driver once, discards stale input; false if the driver will not install. */
bool serial_link_open(serial_link_t *link);

/** XRCE close: the driver stays installed for the next open. */
bool serial_link_close(serial_link_t *link);

/** XRCE write: every byte or, with *err set to 1, as many as went out before the timeout. */
size_t serial_link_write(serial_link_t *link, const uint8_t *buf, size_t len, uint8_t *err);

/** XRCE read: up to len bytes within timeout_ms; *err set to 1 on a driver error. */
size_t serial_link_read(serial_link_t *link, uint8_t *buf, size_t len, int timeout_ms, uint8_t *err);

/** Whether the host is there (for pinging); input from before a re-attach is discarded. */
bool serial_link_attached(serial_link_t *link);

#ifdef __cplusplus
}
#endif

#endif /* SERIAL_LINK_H */
