/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__PRIMITIVES_SEQUENCE_FUNCTIONS_H_
#define ROSIDL_RUNTIME_C__PRIMITIVES_SEQUENCE_FUNCTIONS_H_
#include "rosidl_runtime_c/primitives_sequence.h"
bool rosidl_runtime_c__uint8__Sequence__init(rosidl_runtime_c__uint8__Sequence * sequence, size_t size);
void rosidl_runtime_c__uint8__Sequence__fini(rosidl_runtime_c__uint8__Sequence * sequence);
bool rosidl_runtime_c__float__Sequence__init(rosidl_runtime_c__float__Sequence * sequence, size_t size);
void rosidl_runtime_c__float__Sequence__fini(rosidl_runtime_c__float__Sequence * sequence);
#endif
