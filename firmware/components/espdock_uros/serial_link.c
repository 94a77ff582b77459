/* Serial byte link behind the XRCE custom transport; see serial_link.h. No ESP-IDF includes. */
#include "serial_link.h"

static bool host_present(const serial_link_t *link)
{
    return link->ops.attached == NULL || link->ops.attached(link->ops.hw);
}

void serial_link_init(serial_link_t *link, const serial_link_ops_t *ops)
{
    link->ops = *ops;
    link->installed = false;
    link->open = false;
    link->was_attached = true;
    link->opens = 0;
    link->reattaches = 0;
    link->failed_writes = 0;
}

bool serial_link_attached(serial_link_t *link)
{
    bool now = host_present(link);
    if (now && !link->was_attached) {
        link->reattaches++;
        if (link->installed) {
            /* Whatever the port held from before the unplug belongs to a dead session. */
            link->ops.discard_input(link->ops.hw);
        }
    }
    link->was_attached = now;
    return now;
}

bool serial_link_open(serial_link_t *link)
{
    if (!link->installed) {
        if (!link->ops.install(link->ops.hw)) {
            return false;
        }
        link->installed = true;
    }
    (void)serial_link_attached(link);
    /* A reply to an earlier ping, or a frame cut by a reset, would otherwise be read first. */
    link->ops.discard_input(link->ops.hw);
    link->open = true;
    link->opens++;
    return true;
}

bool serial_link_close(serial_link_t *link)
{
    link->open = false;
    return true;
}

size_t serial_link_write(serial_link_t *link, const uint8_t *buf, size_t len, uint8_t *err)
{
    size_t sent = 0;
    if (!link->installed || !serial_link_attached(link)) {
        /* Fail at once: waiting out the timeout for an absent host would stall the app's loop. */
        link->failed_writes++;
        *err = 1;
        return 0;
    }
    int64_t deadline = link->ops.now_ms(link->ops.hw) + link->ops.write_timeout_ms;
    while (sent < len) {
        int64_t left = deadline - link->ops.now_ms(link->ops.hw);
        int n = link->ops.write(link->ops.hw, buf + sent, len - sent, left > 0 ? (uint32_t)left : 0u);
        if (n < 0) {
            break;
        }
        sent += (size_t)n;
        if (n == 0 && left <= 0) {
            break;
        }
    }
    if (sent < len) {
        link->failed_writes++;
        *err = 1;
    }
    return sent;
}

size_t serial_link_read(serial_link_t *link, uint8_t *buf, size_t len, int timeout_ms, uint8_t *err)
{
    if (!link->installed) {
        *err = 1;
        return 0;
    }
    (void)serial_link_attached(link);
    int n = link->ops.read(link->ops.hw, buf, len, timeout_ms > 0 ? (uint32_t)timeout_ms : 0u);
    if (n < 0) {
        *err = 1;
        return 0;
    }
    return (size_t)n;
}
