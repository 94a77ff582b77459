/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW__QOS_PROFILES_H_
#define RMW__QOS_PROFILES_H_
#include "rmw/types.h"
extern const rmw_qos_profile_t rmw_qos_profile_default;
extern const rmw_qos_profile_t rmw_qos_profile_sensor_data;
extern const rmw_qos_profile_t rmw_qos_profile_services_default;
extern const rmw_qos_profile_t rmw_qos_profile_parameters;
extern const rmw_qos_profile_t rmw_qos_profile_system_default;
#endif
