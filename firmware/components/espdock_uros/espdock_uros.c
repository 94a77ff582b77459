/* micro-ROS session glue; see espdock_uros.h. */
#include "espdock_uros.h"

#include <stdio.h>
#include <string.h>

#include <rcl/context.h>
#include <rmw_microros/rmw_microros.h>

#include "esp_log.h"
#include "esp_timer.h"
#include "espdock_transport.h"
#include "net_settings.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"

#define PING_TIMEOUT_MS 100
#define PING_ATTEMPTS 1
#define SYNC_TIMEOUT_MS 200
#define RESYNC_PERIOD_MS 60000      /* crystal drift stays well under a millisecond */
#define UNSYNCED_RETRY_MS 5000

static const char *TAG = "espdock_uros";

int64_t espdock_uros_now_ms(void)
{
    return esp_timer_get_time() / 1000;
}

bool espdock_uros_setup(espdock_uros_t *uros, const espdock_uros_config_t *config)
{
    memset(uros, 0, sizeof *uros);
    uros->allocator = rcl_get_default_allocator();
    uros->init_options = rcl_get_zero_initialized_init_options();
    uros->node_name = config->node_name;
    uros->node_namespace = config->node_namespace != NULL ? config->node_namespace : "";

#ifdef MAX_PORT_LEN
    /* Only this port is refused, not the build: the library would cut it to port/10 and the
     * board would talk to another port while pings to the right agent never arrive. */
    if (!net_agent_port_fits(config->agent_port, MAX_PORT_LEN)) {
        ESP_LOGE(TAG, "agent port %u: this micro-ROS library keeps only %u digits of a port (rmw_microxrcedds "
                      "MAX_PORT_LEN %u, before micro-ROS/rmw_microxrcedds#315); use an agent port below 10000 "
                      "or rebuild micro-ROS with #315",
                 (unsigned)config->agent_port, (unsigned)(MAX_PORT_LEN - 1), (unsigned)MAX_PORT_LEN);
        return false;
    }
#endif
    ESPDOCK_RC_CHECK(rcl_init_options_init(&uros->init_options, uros->allocator));
    ESPDOCK_RC_CHECK(rcl_init_options_set_domain_id(&uros->init_options, config->domain_id));
    rmw_init_options_t *rmw_options = rcl_init_options_get_rmw_init_options(&uros->init_options);
    if (!espdock_transport_configure(rmw_options, config->agent_ip, config->agent_port)) {
        return false;
    }
    ESP_LOGI(TAG, "agent over %s, node %s", espdock_transport_name(), config->node_name);
    return true;
}

bool espdock_uros_ping(espdock_uros_t *uros, bool in_session)
{
    if (!espdock_transport_is_up()) {
        return false;
    }
    if (in_session) {
        return rmw_uros_ping_agent(PING_TIMEOUT_MS, PING_ATTEMPTS) == RMW_RET_OK;
    }
    /* Without a session, rmw_uros_ping_agent() would use the address compiled
     * into the library, not the one configured here. */
    rmw_init_options_t *rmw_options = rcl_init_options_get_rmw_init_options(&uros->init_options);
    return rmw_uros_ping_agent_options(PING_TIMEOUT_MS, PING_ATTEMPTS, rmw_options) == RMW_RET_OK;
}

static void sync_clock(espdock_uros_t *uros)
{
    uros->last_sync_attempt_ms = espdock_uros_now_ms();
    if (rmw_uros_sync_session(SYNC_TIMEOUT_MS) != RMW_RET_OK) {
        ESP_LOGW(TAG, "time sync with the agent failed; stamps use %s",
                 rmw_uros_epoch_synchronized() ? "the previous offset" : "time since boot");
    }
    uros->clock_synced = rmw_uros_epoch_synchronized();
}

bool espdock_uros_open(espdock_uros_t *uros)
{
    memset(&uros->support, 0, sizeof uros->support);
    uros->support.context = rcl_get_zero_initialized_context();
    uros->node = rcl_get_zero_initialized_node();
    uros->clock_synced = false;
    ESPDOCK_RC_CHECK(rclc_support_init_with_options(&uros->support, 0, NULL, &uros->init_options,
                                                    &uros->allocator));
    ESPDOCK_RC_CHECK(rclc_node_init_default(&uros->node, uros->node_name, uros->node_namespace,
                                            &uros->support));
    sync_clock(uros);
    return true;
}

void espdock_uros_begin_teardown(espdock_uros_t *uros)
{
    if (!rcl_context_is_valid(&uros->support.context)) {
        return;
    }
    rmw_context_t *rmw_context = rcl_context_get_rmw_context(&uros->support.context);
    if (rmw_context != NULL) {
        /* The agent is usually gone: send deletions best effort instead of
         * waiting the creation/destroy timeout for each entity. */
        (void)rmw_uros_set_context_entity_destroy_session_timeout(rmw_context, 0);
    }
}

void espdock_uros_close(espdock_uros_t *uros)
{
    /* A zero-initialised node (creation failed earlier) finalises as a no-op. */
    (void)rcl_node_fini(&uros->node);
    if (rcl_context_is_valid(&uros->support.context)) {
        (void)rclc_support_fini(&uros->support);
    }
    rcl_reset_error();
    uros->clock_synced = false;
}

void espdock_uros_keep_clock(espdock_uros_t *uros)
{
    int64_t period = uros->clock_synced ? RESYNC_PERIOD_MS : UNSYNCED_RETRY_MS;
    if (espdock_uros_now_ms() - uros->last_sync_attempt_ms >= period) {
        sync_clock(uros);
    }
}

void espdock_uros_stamp(builtin_interfaces__msg__Time *stamp)
{
    int64_t ns = rmw_uros_epoch_nanos();
    stamp->sec = (int32_t)(ns / 1000000000LL);
    stamp->nanosec = (uint32_t)(ns % 1000000000LL);
}

void espdock_uros_run(agent_link_t *link, uint32_t step_delay_ms)
{
    TickType_t delay = pdMS_TO_TICKS(step_delay_ms);
    for (;;) {
        agent_link_step(link, espdock_uros_now_ms());
        /* Always yield at least one tick so the idle task (and its watchdog) runs. */
        vTaskDelay(delay > 0 ? delay : 1);
    }
}

/* agent_link has one context; serving needs both the session and the app. */
typedef struct {
    espdock_uros_t *uros;
    espdock_uros_app_t app;
} serve_ctx_t;

static bool serve_ping(void *ctx, bool in_session)
{
    serve_ctx_t *serve = ctx;
    return espdock_uros_ping(serve->uros, in_session);
}

static bool serve_create(void *ctx)
{
    serve_ctx_t *serve = ctx;
    return serve->app.create_entities(serve->app.ctx);
}

static void serve_destroy(void *ctx)
{
    serve_ctx_t *serve = ctx;
    serve->app.destroy_entities(serve->app.ctx);
}

static void serve_spin(void *ctx)
{
    serve_ctx_t *serve = ctx;
    serve->app.spin(serve->app.ctx);
}

static void serve_log_change(void *ctx, agent_link_state_t from, agent_link_state_t to)
{
    (void)ctx;
    ESP_LOGI(TAG, "agent link %s -> %s", agent_link_state_name(from), agent_link_state_name(to));
}

void espdock_uros_serve(espdock_uros_t *uros, const espdock_uros_config_t *config, espdock_uros_app_t app,
                        uint32_t step_delay_ms)
{
    if (!espdock_uros_setup(uros, config)) {
        ESP_LOGE(TAG, "micro-ROS setup failed for agent %s:%u, node %s (see above): node not started, "
                      "its task ends; fix the settings (espdock provision) and reset the board",
                 config->agent_ip, (unsigned)config->agent_port, config->node_name);
        vTaskDelete(NULL);
        return;
    }
    /* Lives as long as the loop below, which never returns. */
    serve_ctx_t serve = {.uros = uros, .app = app};
    const agent_link_ops_t ops = {
        .ping = serve_ping,
        .create_entities = serve_create,
        .destroy_entities = serve_destroy,
        .spin = serve_spin,
        .on_change = serve_log_change,
        .ctx = &serve,
        .waiting_ping_period_ms = ESPDOCK_UROS_WAITING_PING_MS,
        .connected_ping_period_ms = ESPDOCK_UROS_CONNECTED_PING_MS,
        .missed_pings_to_drop = ESPDOCK_UROS_MISSED_PINGS_TO_DROP,
    };
    agent_link_t link;
    agent_link_init(&link, &ops, espdock_uros_now_ms());
    espdock_uros_run(&link, step_delay_ms);
}
