/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__STRING_FUNCTIONS_H_
#define ROSIDL_RUNTIME_C__STRING_FUNCTIONS_H_
#include <stdbool.h>
#include <stddef.h>
#include "rosidl_runtime_c/string.h"
bool rosidl_runtime_c__String__init(rosidl_runtime_c__String * str);
void rosidl_runtime_c__String__fini(rosidl_runtime_c__String * str);
bool rosidl_runtime_c__String__assign(rosidl_runtime_c__String * str, const char * value);
bool rosidl_runtime_c__String__assignn(rosidl_runtime_c__String * str, const char * value, size_t n);
bool rosidl_runtime_c__String__Sequence__init(rosidl_runtime_c__String__Sequence * sequence, size_t size);
void rosidl_runtime_c__String__Sequence__fini(rosidl_runtime_c__String__Sequence * sequence);
#endif
