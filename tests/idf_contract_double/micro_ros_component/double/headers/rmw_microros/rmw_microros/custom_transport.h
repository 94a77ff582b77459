/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). Upstream takes the callback
 * types and struct uxrCustomTransport from Micro-XRCE-DDS-Client's
 * uxr/client/profile/transport/custom/custom_transport.h; the double declares them here. */
#ifndef RMW_MICROROS__CUSTOM_TRANSPORT_H_
#define RMW_MICROROS__CUSTOM_TRANSPORT_H_
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "rmw/types.h"
#define MICROROS_TRANSPORTS_FRAMING_MODE 1
#define MICROROS_TRANSPORTS_PACKET_MODE 0
struct uxrCustomTransport;
typedef bool (* open_custom_func)(struct uxrCustomTransport * transport);
typedef bool (* close_custom_func)(struct uxrCustomTransport * transport);
typedef size_t (* write_custom_func)(
  struct uxrCustomTransport * transport, const uint8_t * buffer, size_t length, uint8_t * error_code);
typedef size_t (* read_custom_func)(
  struct uxrCustomTransport * transport, uint8_t * buffer, size_t length, int timeout, uint8_t * error_code);
typedef struct uxrCustomTransport
{
  bool framing;
  open_custom_func open;
  close_custom_func close;
  write_custom_func write;
  read_custom_func read;
  void * args;
} uxrCustomTransport;
rmw_ret_t rmw_uros_set_custom_transport(
  bool framing, void * args, open_custom_func open_cb, close_custom_func close_cb,
  write_custom_func write_cb, read_custom_func read_cb);
rmw_ret_t rmw_uros_options_set_custom_transport(
  bool framing, void * args, open_custom_func open_cb, close_custom_func close_cb,
  write_custom_func write_cb, read_custom_func read_cb, rmw_init_options_t * rmw_options);
#endif
