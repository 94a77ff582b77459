/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__SERVICE_H_
#define RCL__SERVICE_H_
#include "rcl/node.h"
typedef struct rcl_service_s
{
  void * impl;
} rcl_service_t;
rcl_service_t rcl_get_zero_initialized_service(void);
rcl_ret_t rcl_service_fini(rcl_service_t * service, rcl_node_t * node);
#endif
