/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCUTILS__LOGGING_MACROS_H_
#define RCUTILS__LOGGING_MACROS_H_
#define RCUTILS_LOG_DEBUG(...) ((void)0)
#define RCUTILS_LOG_INFO(...) ((void)0)
#define RCUTILS_LOG_WARN(...) ((void)0)
#define RCUTILS_LOG_ERROR(...) ((void)0)
#endif
