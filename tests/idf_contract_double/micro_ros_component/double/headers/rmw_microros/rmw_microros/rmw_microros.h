/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__RMW_MICROROS_H_
#define RMW_MICROROS__RMW_MICROROS_H_
#include "rmw_microros/init_options.h"
#include "rmw_microros/ping.h"
#include "rmw_microros/time_sync.h"
#include "rmw_microros/timing.h"
#endif
