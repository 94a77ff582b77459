/* Choosing and checking the network settings; see net_settings.h. No ESP-IDF includes. */
#include "net_settings.h"

#include <stdio.h>
#include <string.h>

static bool present(const char *text)
{
    return text != NULL && text[0] != '\0';
}

static bool copy_bounded(char *dest, size_t size, const char *src, size_t min_len)
{
    size_t len = strlen(src);
    if (len < min_len || len >= size) {
        dest[0] = '\0';
        return false;
    }
    memcpy(dest, src, len + 1);
    return true;
}

static bool printable_ascii(const char *text)
{
    for (const unsigned char *c = (const unsigned char *)text; *c != '\0'; c++) {
        if (*c < 0x20 || *c > 0x7e) {
            return false;
        }
    }
    return true;
}

bool net_is_ipv4(const char *text)
{
    unsigned parts = 0;
    bool all_zero = true;
    const char *c = text;
    if (text == NULL || strlen(text) > NET_HOST_MAX) {
        return false;
    }
    for (;;) {
        unsigned value = 0;
        unsigned digits = 0;
        const char *start = c;
        while (*c >= '0' && *c <= '9') {
            value = value * 10u + (unsigned)(*c - '0');
            digits++;
            c++;
        }
        /* "010" is octal to some parsers and decimal to others: refuse it. */
        if (digits == 0 || digits > 3 || value > 255 || (digits > 1 && *start == '0')) {
            return false;
        }
        all_zero = all_zero && value == 0;
        parts++;
        if (*c == '\0') {
            break;
        }
        if (*c != '.' || parts == 4) {
            return false;
        }
        c++;
    }
    return parts == 4 && !all_zero;
}

uint32_t net_settings_choose(const net_candidate_t *nvs, const net_candidate_t *kconfig, net_settings_t *out)
{
    uint32_t problems = 0;
    memset(out, 0, sizeof *out);

    const net_candidate_t *credentials = NULL;
    if (present(nvs->ssid)) {
        credentials = nvs;
        out->ssid_from = NET_FROM_NVS;
    } else if (present(kconfig->ssid)) {
        credentials = kconfig;
        out->ssid_from = NET_FROM_KCONFIG;
    }
    if (credentials == NULL) {
        problems |= NET_MISSING_SSID;
    } else {
        if (!copy_bounded(out->ssid, sizeof out->ssid, credentials->ssid, 1)) {
            problems |= NET_BAD_SSID;
        }
        out->password_from = out->ssid_from;
        const char *password = credentials->password != NULL ? credentials->password : "";
        bool open = password[0] == '\0';
        if (!open && (!printable_ascii(password) ||
                      !copy_bounded(out->password, sizeof out->password, password, NET_PASSWORD_MIN))) {
            out->password[0] = '\0';
            problems |= NET_BAD_PASSWORD;
        }
    }

    const char *host = present(nvs->agent_host) ? nvs->agent_host : kconfig->agent_host;
    if (!present(host)) {
        problems |= NET_MISSING_AGENT_HOST;
    } else {
        out->agent_host_from = host == nvs->agent_host ? NET_FROM_NVS : NET_FROM_KCONFIG;
        if (!net_is_ipv4(host) || !copy_bounded(out->agent_host, sizeof out->agent_host, host, 1)) {
            out->agent_host[0] = '\0';
            problems |= NET_BAD_AGENT_HOST;
        }
    }

    const net_candidate_t *port = nvs->has_agent_port ? nvs : kconfig->has_agent_port ? kconfig : NULL;
    if (port == NULL) {
        problems |= NET_MISSING_AGENT_PORT;
    } else {
        out->agent_port_from = port == nvs ? NET_FROM_NVS : NET_FROM_KCONFIG;
        if (port->agent_port == 0 || port->agent_port > 65535u) {
            problems |= NET_BAD_AGENT_PORT;
        } else {
            out->agent_port = (uint16_t)port->agent_port;
        }
    }

    const net_candidate_t *domain = nvs->has_domain_id ? nvs : kconfig->has_domain_id ? kconfig : NULL;
    if (domain != NULL) {
        out->domain_id_from = domain == nvs ? NET_FROM_NVS : NET_FROM_KCONFIG;
        if (domain->domain_id > NET_DOMAIN_ID_MAX) {
            problems |= NET_BAD_DOMAIN_ID;
        } else {
            out->domain_id = (uint8_t)domain->domain_id;
        }
    }
    return problems;
}

const char *net_describe_problems(uint32_t problems, char *buf, size_t size)
{
    static const struct {
        uint32_t bit;
        const char *text;
    } names[] = {
        {NET_MISSING_SSID, "no Wi-Fi SSID"},
        {NET_MISSING_AGENT_HOST, "no agent address"},
        {NET_MISSING_AGENT_PORT, "no agent port"},
        {NET_BAD_SSID, "SSID is not 1..32 bytes"},
        {NET_BAD_PASSWORD, "password is not 8..63 printable ASCII characters"},
        {NET_BAD_AGENT_HOST, "agent address is not an IPv4 address"},
        {NET_BAD_AGENT_PORT, "agent port is not 1..65535"},
        {NET_BAD_DOMAIN_ID, "domain id is not 0..232"},
    };
    size_t used = 0;
    if (size == 0) {
        return buf;
    }
    buf[0] = '\0';
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        if ((problems & names[i].bit) == 0) {
            continue;
        }
        int n = snprintf(buf + used, size - used, "%s%s", used > 0 ? "; " : "", names[i].text);
        if (n < 0 || (size_t)n >= size - used) {
            buf[used] = '\0';    /* whole items only: a cut-off one reads as a different problem */
            break;
        }
        used += (size_t)n;
    }
    return buf;
}

const char *net_source_name(net_source_t source)
{
    switch (source) {
    case NET_FROM_NVS:
        return "NVS";
    case NET_FROM_KCONFIG:
        return "Kconfig";
    default:
        return "nowhere";
    }
}

bool net_agent_port_fits(uint32_t port, uint32_t max_port_len)
{
    uint32_t digits = 1;
    for (uint32_t rest = port / 10u; rest != 0u; rest /= 10u) {
        digits++;
    }
    return max_port_len >= 1u && digits <= max_port_len - 1u;
}

int net_nvs_ready(const net_nvs_ops_t *ops, bool *ready)
{
    if (*ready) {
        return 0;
    }
    int err = ops->init();
    if (err != 0 && ops->erase_repairs(err)) {
        ops->on_erase(err);
        err = ops->erase();
        if (err == 0) {
            err = ops->init();
        }
    }
    *ready = err == 0;
    return err;
}
