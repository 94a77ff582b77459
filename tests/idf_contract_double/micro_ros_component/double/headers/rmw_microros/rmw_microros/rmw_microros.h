/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__RMW_MICROROS_H_
#define RMW_MICROROS__RMW_MICROROS_H_
#include "rmw_microros/init_options.h"
#include "rmw_microros/ping.h"
#include "rmw_microros/time_sync.h"
#include "rmw_microros/timing.h"
#include "rmw_microros/custom_transport.h"
/* The agent port's buffer length, as rmw_microxrcedds before micro-ROS/rmw_microxrcedds#315 has it
 * (the jazzy head espdock follows unless #315 reached it: its backports were asked for iron and
 * humble): the library keeps MAX_PORT_LEN - 1 = 4 digits of a port. */
#define MAX_PORT_LEN         5
#endif
