/* Host tests for firmware/components/espdock_uros/net_settings.c */
#include <string.h>

#include "net_settings.h"
#include "testkit.h"

static const net_candidate_t NONE = {0};

/* What a build with espdock's Kconfig defaults carries: nothing but the port and domain. */
static const net_candidate_t KCONFIG_DEFAULTS = {
    .ssid = "", .password = "", .agent_host = "",
    .has_agent_port = true, .agent_port = 8888, .has_domain_id = true, .domain_id = 0,
};

static const net_candidate_t PROVISIONED = {
    .ssid = "lab-net", .password = "correct horse", .agent_host = "10.0.0.2",
    .has_agent_port = true, .agent_port = 9999, .has_domain_id = true, .domain_id = 42,
};

static void test_nvs_values_win(void)
{
    net_settings_t s;
    uint32_t problems = net_settings_choose(&PROVISIONED, &KCONFIG_DEFAULTS, &s);
    TK_CHECK_EQ_INT(problems, 0, "problems");
    TK_CHECK(strcmp(s.ssid, "lab-net") == 0, "ssid %s", s.ssid);
    TK_CHECK(strcmp(s.password, "correct horse") == 0, "password");
    TK_CHECK(strcmp(s.agent_host, "10.0.0.2") == 0, "host %s", s.agent_host);
    TK_CHECK_EQ_INT(s.agent_port, 9999, "port");
    TK_CHECK_EQ_INT(s.domain_id, 42, "domain");
    TK_CHECK(s.ssid_from == NET_FROM_NVS && s.password_from == NET_FROM_NVS, "credentials from NVS");
    TK_CHECK(s.agent_host_from == NET_FROM_NVS && s.agent_port_from == NET_FROM_NVS, "agent from NVS");
    TK_CHECK(s.domain_id_from == NET_FROM_NVS, "domain from NVS");
}

static void test_unprovisioned_default_build_says_what_is_missing(void)
{
    net_settings_t s;
    uint32_t problems = net_settings_choose(&NONE, &KCONFIG_DEFAULTS, &s);
    TK_CHECK_EQ_INT(problems, NET_MISSING_SSID | NET_MISSING_AGENT_HOST, "problems");
    char text[160];
    net_describe_problems(problems, text, sizeof text);
    TK_CHECK(strcmp(text, "no Wi-Fi SSID; no agent address") == 0, "description '%s'", text);
}

static void test_each_key_falls_back_to_kconfig(void)
{
    const net_candidate_t kconfig = {
        .ssid = "build-net", .password = "build-pass", .agent_host = "192.168.1.5",
        .has_agent_port = true, .agent_port = 8888, .has_domain_id = true, .domain_id = 3,
    };
    const net_candidate_t nvs_host_only = {.agent_host = "10.1.2.3"};
    net_settings_t s;
    TK_CHECK_EQ_INT(net_settings_choose(&nvs_host_only, &kconfig, &s), 0, "problems");
    TK_CHECK(strcmp(s.ssid, "build-net") == 0 && s.ssid_from == NET_FROM_KCONFIG, "ssid from Kconfig");
    TK_CHECK(strcmp(s.password, "build-pass") == 0 && s.password_from == NET_FROM_KCONFIG, "password");
    TK_CHECK(strcmp(s.agent_host, "10.1.2.3") == 0 && s.agent_host_from == NET_FROM_NVS, "host from NVS");
    TK_CHECK(s.agent_port == 8888 && s.agent_port_from == NET_FROM_KCONFIG, "port from Kconfig");
    TK_CHECK(s.domain_id == 3 && s.domain_id_from == NET_FROM_KCONFIG, "domain from Kconfig");
}

static void test_password_follows_the_ssid(void)
{
    const net_candidate_t kconfig = {
        .ssid = "build-net", .password = "build-pass", .agent_host = "192.168.1.5",
        .has_agent_port = true, .agent_port = 8888,
    };
    const net_candidate_t open_nvs = {.ssid = "cafe"};    /* provisioned open network */
    net_settings_t s;
    TK_CHECK_EQ_INT(net_settings_choose(&open_nvs, &kconfig, &s), 0, "problems");
    TK_CHECK(strcmp(s.ssid, "cafe") == 0, "ssid");
    TK_CHECK(s.password[0] == '\0' && s.password_from == NET_FROM_NVS,
             "an NVS SSID never gets the build's password");
    TK_CHECK(s.domain_id == 0 && s.domain_id_from == NET_FROM_NONE, "no domain anywhere is 0");
}

static void expect_problem(net_candidate_t nvs, uint32_t want, const char *what)
{
    net_settings_t s;
    uint32_t problems = net_settings_choose(&nvs, &KCONFIG_DEFAULTS, &s);
    TK_CHECK(problems == want, "%s: problems 0x%x, want 0x%x", what, (unsigned)problems, (unsigned)want);
}

static void test_bad_values_are_refused(void)
{
    net_candidate_t base = PROVISIONED;
    net_candidate_t c;

    c = base;
    c.ssid = "123456789012345678901234567890123";    /* 33 bytes */
    expect_problem(c, NET_BAD_SSID, "33-byte SSID");
    c.ssid = "12345678901234567890123456789012";     /* 32 bytes */
    expect_problem(c, 0, "32-byte SSID");

    c = base;
    c.password = "short";
    expect_problem(c, NET_BAD_PASSWORD, "5-character password");
    c.password = "1234567";
    expect_problem(c, NET_BAD_PASSWORD, "7-character password");
    c.password = "12345678";
    expect_problem(c, 0, "8-character password");
    c.password = "123456789012345678901234567890123456789012345678901234567890123";
    expect_problem(c, 0, "63-character password");
    c.password = "1234567890123456789012345678901234567890123456789012345678901234";
    expect_problem(c, NET_BAD_PASSWORD, "64 characters");
    c.password = "tab\there!";
    expect_problem(c, NET_BAD_PASSWORD, "control character");

    c = base;
    c.agent_host = "agent.local";
    expect_problem(c, NET_BAD_AGENT_HOST, "a hostname");
    c.has_agent_port = true;
    c.agent_port = 0;
    c.agent_host = "10.0.0.2";
    expect_problem(c, NET_BAD_AGENT_PORT, "port 0");
    c.agent_port = 65536;
    expect_problem(c, NET_BAD_AGENT_PORT, "port 65536");

    c = base;
    c.domain_id = 233;
    expect_problem(c, NET_BAD_DOMAIN_ID, "domain 233");
    c.domain_id = 232;
    expect_problem(c, 0, "domain 232");
}

static void test_ipv4_parsing(void)
{
    static const char *good[] = {"10.0.0.2", "192.168.1.100", "255.255.255.255", "1.2.3.4", "127.0.0.1"};
    static const char *bad[] = {
        "", "0.0.0.0", "10.0.0", "10.0.0.2.", "10.0.0.2.5", "256.1.1.1", "1.2.3.04", "01.2.3.4",
        "a.b.c.d", "10..0.2", " 10.0.0.2", "10.0.0.2 ", "1234.1.1.1", "-1.2.3.4", "::1",
    };
    for (size_t i = 0; i < sizeof good / sizeof good[0]; i++) {
        TK_CHECK(net_is_ipv4(good[i]), "'%s' refused", good[i]);
    }
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        TK_CHECK(!net_is_ipv4(bad[i]), "'%s' accepted", bad[i]);
    }
    TK_CHECK(!net_is_ipv4(NULL), "NULL accepted");
}

static void test_description_fits_a_small_buffer(void)
{
    char text[20];
    net_describe_problems(0xffu, text, sizeof text);
    TK_CHECK(strlen(text) < sizeof text, "overflow");
    TK_CHECK(strcmp(text, "no Wi-Fi SSID") == 0, "whole items only, got '%s'", text);
}

/* rmw_microxrcedds keeps MAX_PORT_LEN - 1 digits: 5 before micro-ROS/rmw_microxrcedds#315, 6 after. */
static void test_agent_ports_the_library_would_cut_are_refused_alone(void)
{
    TK_CHECK(net_agent_port_fits(8888, 5), "8888 fits a library before #315");
    TK_CHECK(net_agent_port_fits(9999, 5), "9999 fits a library before #315");
    TK_CHECK(!net_agent_port_fits(10000, 5), "10000 would become 1000");
    TK_CHECK(!net_agent_port_fits(65535, 5), "65535 would become 6553");
    TK_CHECK(net_agent_port_fits(10000, 6) && net_agent_port_fits(65535, 6), "five digits fit after #315");
    TK_CHECK(net_agent_port_fits(1, 2) && !net_agent_port_fits(10, 2), "one digit in char[2]");
    TK_CHECK(!net_agent_port_fits(1, 0) && !net_agent_port_fits(1, 1), "no room for any digit");
}

/* A scripted nvs_flash_init/nvs_flash_erase: each call takes the next result. */
enum { NVS_OK = 0, NVS_NO_FREE_PAGES = 0x110d, NVS_NOT_INITIALIZED = 0x1101 };
static int s_init_results[8];
static unsigned s_init_calls, s_erase_calls, s_erase_logs;

static int scripted_init(void)
{
    return s_init_results[s_init_calls++];
}

static int scripted_erase(void)
{
    s_erase_calls++;
    return NVS_OK;
}

static bool scripted_repairs(int err)
{
    return err == NVS_NO_FREE_PAGES;
}

static void scripted_on_erase(int err)
{
    (void)err;
    s_erase_logs++;
}

static const net_nvs_ops_t SCRIPTED = {
    .init = scripted_init, .erase = scripted_erase, .erase_repairs = scripted_repairs, .on_erase = scripted_on_erase,
};

static void script(int first, int second, int third)
{
    s_init_calls = s_erase_calls = s_erase_logs = 0;
    s_init_results[0] = first;
    s_init_results[1] = second;
    s_init_results[2] = third;
}

static void test_a_failed_nvs_init_is_tried_again_on_the_next_call(void)
{
    bool ready = false;
    script(NVS_NOT_INITIALIZED, NVS_OK, NVS_NOT_INITIALIZED);
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_NOT_INITIALIZED, "first attempt fails");
    TK_CHECK(!ready, "not ready after a failure");
    /* Wi-Fi's start retry calls again: NVS must be retried, not the first failure returned. */
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_OK, "second attempt succeeds");
    TK_CHECK_EQ_INT(s_init_calls, 2, "nvs_flash_init called again");
    TK_CHECK(ready, "ready after a success");
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_OK, "once ready, stays ready");
    TK_CHECK_EQ_INT(s_init_calls, 2, "no init once ready");
}

static void test_an_unusable_partition_is_erased_once_per_attempt(void)
{
    bool ready = false;
    script(NVS_NO_FREE_PAGES, NVS_OK, NVS_OK);
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_OK, "erase and init again");
    TK_CHECK(s_erase_calls == 1 && s_erase_logs == 1, "erased once, and said so");
    TK_CHECK(ready, "ready");
    ready = false;
    script(NVS_NO_FREE_PAGES, NVS_NO_FREE_PAGES, NVS_OK);
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_NO_FREE_PAGES, "still unusable after the erase");
    TK_CHECK(!ready && s_erase_calls == 1, "one erase per attempt");
    TK_CHECK_EQ_INT(net_nvs_ready(&SCRIPTED, &ready), NVS_OK, "the next attempt succeeds");
}

int main(void)
{
    test_agent_ports_the_library_would_cut_are_refused_alone();
    test_a_failed_nvs_init_is_tried_again_on_the_next_call();
    test_an_unusable_partition_is_erased_once_per_attempt();
    test_nvs_values_win();
    test_unprovisioned_default_build_says_what_is_missing();
    test_each_key_falls_back_to_kconfig();
    test_password_follows_the_ssid();
    test_bad_values_are_refused();
    test_ipv4_parsing();
    test_description_fits_a_small_buffer();
    return tk_report("net_settings");
}
