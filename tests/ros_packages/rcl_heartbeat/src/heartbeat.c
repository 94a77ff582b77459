// A node in C on rcl alone: init, one node, a log line, shutdown.
#include <stdio.h>

#include <rcl/rcl.h>
#include <rcutils/logging_macros.h>

int main(int argc, char ** argv)
{
  rcl_allocator_t allocator = rcl_get_default_allocator();
  rcl_init_options_t options = rcl_get_zero_initialized_init_options();
  if (rcl_init_options_init(&options, allocator) != RCL_RET_OK) {
    return 1;
  }
  rcl_context_t context = rcl_get_zero_initialized_context();
  if (rcl_init(argc, (const char * const *)argv, &options, &context) != RCL_RET_OK) {
    return 1;
  }
  rcl_node_t node = rcl_get_zero_initialized_node();
  rcl_node_options_t node_options = rcl_node_get_default_options();
  if (rcl_node_init(&node, "heartbeat", "", &context, &node_options) != RCL_RET_OK) {
    return 1;
  }
  RCUTILS_LOG_INFO_NAMED("heartbeat", "alive");
  rcl_ret_t ret = rcl_node_fini(&node);
  ret |= rcl_shutdown(&context);
  ret |= rcl_context_fini(&context);
  ret |= rcl_init_options_fini(&options);
  return ret == RCL_RET_OK ? 0 : 1;
}
