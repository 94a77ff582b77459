/*
 * Host tests for firmware/components/espdock_uros/serial_link.c: a fake serial
 * port (a cable that can be pulled, a TX buffer the host drains, a clock) and,
 * for reconnection, agent_link driving pings through the link to a fake agent.
 */
#include <string.h>

#include "agent_link.h"
#include "serial_link.h"
#include "testkit.h"

#define FIFO_MAX 256

typedef struct {
    uint8_t rx[FIFO_MAX];       /* host -> board, not yet read */
    size_t rx_len;
    uint8_t tx[FIFO_MAX];       /* board -> host, not yet taken by the host */
    size_t tx_len;
    size_t tx_room;             /* what the driver's TX buffer takes before it blocks */
    bool plugged;
    bool can_tell_plugged;      /* USB-Serial-JTAG can; a UART cannot */
    bool host_reading;          /* the host drains TX (a port opened by the agent) */
    bool install_fails;
    int installs;
    int discards;
    int64_t now;
} port_t;

static bool port_install(void *hw)
{
    port_t *p = hw;
    p->installs++;
    return !p->install_fails;
}

static int port_write(void *hw, const uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    port_t *p = hw;
    if (p->plugged && p->host_reading) {
        p->tx_len = 0;          /* the host took everything queued so far */
    }
    size_t room = p->tx_room - p->tx_len;
    size_t n = len < room ? len : room;
    memcpy(p->tx + p->tx_len, buf, n);
    p->tx_len += n;
    if (n < len) {
        p->now += timeout_ms;   /* blocked for the whole timeout, as the drivers do */
    }
    return (int)n;
}

static int port_read(void *hw, uint8_t *buf, size_t len, uint32_t timeout_ms)
{
    port_t *p = hw;
    size_t n = len < p->rx_len ? len : p->rx_len;
    memcpy(buf, p->rx, n);
    memmove(p->rx, p->rx + n, p->rx_len - n);
    p->rx_len -= n;
    if (n == 0) {
        p->now += timeout_ms;
    }
    return (int)n;
}

static void port_discard(void *hw)
{
    port_t *p = hw;
    p->discards++;
    p->rx_len = 0;
}

static bool port_attached(void *hw)
{
    port_t *p = hw;
    return p->plugged;
}

static int64_t port_now(void *hw)
{
    port_t *p = hw;
    return p->now;
}

static void port_receive(port_t *p, const char *text)
{
    size_t n = strlen(text);
    memcpy(p->rx + p->rx_len, text, n);
    p->rx_len += n;
}

static void port_setup(port_t *p, serial_link_t *link, bool can_tell_plugged)
{
    memset(p, 0, sizeof *p);
    p->tx_room = 64;
    p->plugged = true;
    p->host_reading = true;
    p->can_tell_plugged = can_tell_plugged;
    const serial_link_ops_t ops = {
        .install = port_install,
        .write = port_write,
        .read = port_read,
        .discard_input = port_discard,
        .attached = can_tell_plugged ? port_attached : NULL,
        .now_ms = port_now,
        .hw = p,
        .write_timeout_ms = 50,
    };
    serial_link_init(link, &ops);
}

static void test_the_driver_is_installed_once_across_opens_and_closes(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, true);
    for (int i = 0; i < 5; i++) {
        TK_CHECK(serial_link_open(&link), "open %d", i);
        TK_CHECK(serial_link_close(&link), "close %d", i);
    }
    TK_CHECK_EQ_INT(p.installs, 1, "driver installs over 5 pings' open/close");
    TK_CHECK_EQ_INT(link.opens, 5, "opens");
}

static void test_a_driver_that_fails_to_install_is_retried_on_the_next_open(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, false);
    p.install_fails = true;
    TK_CHECK(!serial_link_open(&link), "open with a failing driver");
    uint8_t err = 0;
    TK_CHECK_EQ_INT(serial_link_write(&link, (const uint8_t *)"x", 1, &err), 0, "bytes written while not installed");
    TK_CHECK_EQ_INT(err, 1, "write error while not installed");
    p.install_fails = false;
    TK_CHECK(serial_link_open(&link), "open once the driver installs");
    TK_CHECK_EQ_INT(p.installs, 2, "install attempts");
}

static void test_open_drops_bytes_no_session_was_listening_for(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, false);
    TK_CHECK(serial_link_open(&link), "open");
    serial_link_close(&link);
    port_receive(&p, "late reply");
    TK_CHECK(serial_link_open(&link), "reopen");
    port_receive(&p, "NEW");
    uint8_t buf[16];
    uint8_t err = 0;
    size_t n = serial_link_read(&link, buf, sizeof buf, 10, &err);
    TK_CHECK(n == 3 && memcmp(buf, "NEW", 3) == 0, "read after reopen: %zu bytes", n);
    TK_CHECK_EQ_INT(err, 0, "read error");
}

static void test_a_write_larger_than_the_tx_buffer_goes_out_whole(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, false);
    p.tx_room = 8;
    serial_link_open(&link);
    /* The host drains between the driver's partial writes: all 30 bytes go out. */
    uint8_t frame[30];
    memset(frame, 0x7e, sizeof frame);
    uint8_t err = 0;
    TK_CHECK_EQ_INT(serial_link_write(&link, frame, sizeof frame, &err), 30, "bytes written");
    TK_CHECK_EQ_INT(err, 0, "write error");
}

static void test_a_write_nobody_reads_fails_after_its_timeout_not_forever(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, false);   /* a UART: it cannot tell that nobody listens */
    p.tx_room = 8;
    p.host_reading = false;
    serial_link_open(&link);
    uint8_t frame[30] = {0};
    uint8_t err = 0;
    int64_t start = p.now;
    size_t n = serial_link_write(&link, frame, sizeof frame, &err);
    TK_CHECK(n < sizeof frame, "wrote %zu of 30 with nobody reading", n);
    TK_CHECK_EQ_INT(err, 1, "write error");
    TK_CHECK(p.now - start <= 2 * 50, "blocked %lld ms (timeout 50)", (long long)(p.now - start));
    TK_CHECK_EQ_INT(link.failed_writes, 1, "failed writes");
}

static void test_with_the_usb_cable_out_writes_fail_at_once(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, true);
    serial_link_open(&link);
    p.plugged = false;
    uint8_t err = 0;
    int64_t start = p.now;
    TK_CHECK_EQ_INT(serial_link_write(&link, (const uint8_t *)"PING", 4, &err), 0, "bytes written unplugged");
    TK_CHECK_EQ_INT(err, 1, "write error unplugged");
    TK_CHECK_EQ_INT(p.now - start, 0, "ms spent writing to an absent host");
    TK_CHECK(!serial_link_attached(&link), "attached while unplugged");
}

static void test_replugging_drops_what_arrived_before_the_cable_was_pulled(void)
{
    port_t p;
    serial_link_t link;
    port_setup(&p, &link, true);
    serial_link_open(&link);
    port_receive(&p, "HALF");   /* a frame cut by the unplug */
    p.plugged = false;
    TK_CHECK(!serial_link_attached(&link), "attached while unplugged");
    p.plugged = true;
    TK_CHECK(serial_link_attached(&link), "attached after replug");
    TK_CHECK_EQ_INT(link.reattaches, 1, "re-attaches");
    TK_CHECK_EQ_INT(p.rx_len, 0, "stale bytes left after replug");
}

/* Reconnection end to end: agent_link pings the fake agent through the link. */
typedef struct {
    port_t port;
    serial_link_t link;
    bool agent_up;
    int creates;
    int destroys;
} rig_t;

static bool rig_ping(void *ctx, bool in_session)
{
    rig_t *r = ctx;
    /* As rmw_uros_ping_agent_options: without a session it opens and closes the transport. */
    if (!in_session && !serial_link_open(&r->link)) {
        return false;
    }
    bool ok = false;
    uint8_t err = 0;
    size_t sent = serial_link_write(&r->link, (const uint8_t *)"PING", 4, &err);
    if (sent == 4 && err == 0 && r->agent_up && r->port.plugged) {
        port_receive(&r->port, "PONG");
    }
    uint8_t reply[8];
    size_t got = serial_link_read(&r->link, reply, 4, 100, &err);
    ok = got == 4 && memcmp(reply, "PONG", 4) == 0;
    if (!in_session) {
        serial_link_close(&r->link);
    }
    return ok;
}

static bool rig_create(void *ctx)
{
    rig_t *r = ctx;
    r->creates++;
    return serial_link_open(&r->link);
}

static void rig_destroy(void *ctx)
{
    rig_t *r = ctx;
    r->destroys++;
    serial_link_close(&r->link);
}

static void rig_spin(void *ctx)
{
    (void)ctx;
}

static agent_link_state_t run_for(rig_t *r, agent_link_t *agent, int64_t ms)
{
    int64_t end = r->port.now + ms;
    while (r->port.now < end) {
        agent_link_step(agent, r->port.now);
        r->port.now += 10;
    }
    return agent->state;
}

static void test_unplug_and_replug_reconnects_for_each_kind_of_port(void)
{
    for (int usb = 0; usb <= 1; usb++) {
        rig_t r;
        memset(&r, 0, sizeof r);
        port_setup(&r.port, &r.link, usb != 0);
        r.agent_up = true;
        const agent_link_ops_t ops = {
            .ping = rig_ping,
            .create_entities = rig_create,
            .destroy_entities = rig_destroy,
            .spin = rig_spin,
            .ctx = &r,
            .waiting_ping_period_ms = 500,
            .connected_ping_period_ms = 200,
            .missed_pings_to_drop = 3,
        };
        agent_link_t agent;
        agent_link_init(&agent, &ops, r.port.now);
        TK_CHECK_EQ_INT(run_for(&r, &agent, 1000), AGENT_LINK_CONNECTED, usb ? "USB: first session" : "UART: first");
        port_receive(&r.port, "PO");    /* the agent's reply, cut by the unplug */
        r.port.plugged = false;
        r.port.host_reading = false;    /* the agent's port is gone */
        TK_CHECK_EQ_INT(run_for(&r, &agent, 2000), AGENT_LINK_WAITING, usb ? "USB: unplugged" : "UART: unplugged");
        TK_CHECK_EQ_INT(r.destroys, 1, "sessions torn down after the unplug");
        r.port.plugged = true;
        r.port.host_reading = true;     /* the agent reopened the device */
        TK_CHECK_EQ_INT(run_for(&r, &agent, 1500), AGENT_LINK_CONNECTED, usb ? "USB: replugged" : "UART: replugged");
        TK_CHECK_EQ_INT(agent.sessions, 2, usb ? "USB: sessions" : "UART: sessions");
        TK_CHECK_EQ_INT(r.port.installs, 1, "driver installs across the reconnection");
    }
}

int main(void)
{
    test_the_driver_is_installed_once_across_opens_and_closes();
    test_a_driver_that_fails_to_install_is_retried_on_the_next_open();
    test_open_drops_bytes_no_session_was_listening_for();
    test_a_write_larger_than_the_tx_buffer_goes_out_whole();
    test_a_write_nobody_reads_fails_after_its_timeout_not_forever();
    test_with_the_usb_cable_out_writes_fail_at_once();
    test_replugging_drops_what_arrived_before_the_cable_was_pulled();
    test_unplug_and_replug_reconnects_for_each_kind_of_port();
    return tk_report("serial_link");
}
