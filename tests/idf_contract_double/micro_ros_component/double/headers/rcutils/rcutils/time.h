/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCUTILS__TIME_H_
#define RCUTILS__TIME_H_
#include <stdint.h>
#define RCUTILS_S_TO_NS(seconds) ((seconds) * (1000LL * 1000LL * 1000LL))
#define RCUTILS_MS_TO_NS(milliseconds) ((milliseconds) * (1000LL * 1000LL))
typedef int64_t rcutils_time_point_value_t;
typedef int64_t rcutils_duration_value_t;
#endif
