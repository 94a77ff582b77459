/* The micro-ROS library must keep all five digits of an agent port. rmw_microxrcedds before
 * micro-ROS/rmw_microxrcedds#315 (issue #314) stores the port in char[MAX_PORT_LEN] with
 * MAX_PORT_LEN 5 and copies it with snprintf(.., MAX_PORT_LEN, ..): "10000".."65535" lose their
 * last digit, so the board talks to port/10 while pings to the right agent never arrive. Such a
 * library fails the build here instead. */
#pragma once

#include <rmw_microros/rmw_microros.h>

#if defined(RMW_UXRCE_TRANSPORT_UDP) || defined(RMW_UXRCE_TRANSPORT_TCP)
_Static_assert(sizeof(((rmw_uxrce_transport_params_t *)0)->agent_port) >= sizeof "65535" && MAX_PORT_LEN >= 5,
               "rmw_microxrcedds keeps only MAX_PORT_LEN - 1 characters of the agent port (agent ports of 10000 "
               "and up would be cut to port/10): pin a rmw_microxrcedds commit with micro-ROS/rmw_microxrcedds#315");
#endif
