/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__U16STRING_H_
#define ROSIDL_RUNTIME_C__U16STRING_H_
#include <stddef.h>
#include <stdint.h>
typedef struct rosidl_runtime_c__U16String
{
  uint16_t * data;
  size_t size;
  size_t capacity;
} rosidl_runtime_c__U16String;
typedef struct rosidl_runtime_c__U16String__Sequence
{
  rosidl_runtime_c__U16String * data;
  size_t size;
  size_t capacity;
} rosidl_runtime_c__U16String__Sequence;
#endif
