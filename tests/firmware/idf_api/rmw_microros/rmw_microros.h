/* Test double of rmw_microros/rmw_microros.h (rmw_microxrcedds jazzy): the declarations of
 * init_options.h and custom_transport.h espdock_transport.c uses, and Micro-XRCE-DDS-Client's
 * custom transport callback types (uxr/client/profile/transport/custom/custom_transport.h). */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <rmw/init_options.h>
typedef int rmw_ret_t;
#define RMW_RET_OK 0
#define MICROROS_TRANSPORTS_FRAMING_MODE 1
#define MICROROS_TRANSPORTS_PACKET_MODE 0
struct uxrCustomTransport;
typedef bool (*open_custom_func)(struct uxrCustomTransport *transport);
typedef bool (*close_custom_func)(struct uxrCustomTransport *transport);
typedef size_t (*write_custom_func)(struct uxrCustomTransport *transport, const uint8_t *buffer, size_t length,
                                    uint8_t *error_code);
typedef size_t (*read_custom_func)(struct uxrCustomTransport *transport, uint8_t *buffer, size_t length, int timeout,
                                   uint8_t *error_code);
typedef struct uxrCustomTransport {
    uint8_t buffer[512];
    bool framing;
    open_custom_func open;
    close_custom_func close;
    write_custom_func write;
    read_custom_func read;
    void *args;
} uxrCustomTransport;
rmw_ret_t rmw_uros_options_set_udp_address(const char *ip, const char *port, rmw_init_options_t *rmw_options);
rmw_ret_t rmw_uros_options_set_custom_transport(bool framing, void *args, open_custom_func open_cb,
                                                close_custom_func close_cb, write_custom_func write_cb,
                                                read_custom_func read_cb, rmw_init_options_t *rmw_options);
