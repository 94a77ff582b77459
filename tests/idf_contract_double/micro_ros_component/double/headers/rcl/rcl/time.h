/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__TIME_H_
#define RCL__TIME_H_
#include "rcutils/time.h"
#define RCL_S_TO_NS RCUTILS_S_TO_NS
#define RCL_MS_TO_NS RCUTILS_MS_TO_NS
typedef rcutils_time_point_value_t rcl_time_point_value_t;
typedef struct rcl_clock_s rcl_clock_t;
#endif
