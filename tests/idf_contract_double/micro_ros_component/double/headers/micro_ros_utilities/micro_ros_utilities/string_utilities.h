/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef MICRO_ROS_UTILITIES__STRING_UTILITIES_H_
#define MICRO_ROS_UTILITIES__STRING_UTILITIES_H_
#include <stdbool.h>
#include "rosidl_runtime_c/string.h"
rosidl_runtime_c__String micro_ros_string_utilities_init(const char * data);
rosidl_runtime_c__String micro_ros_string_utilities_set(const rosidl_runtime_c__String str, const char * data);
void micro_ros_string_utilities_destroy(rosidl_runtime_c__String * const str);
#endif
