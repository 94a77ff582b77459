/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__PRIMITIVES_SEQUENCE_H_
#define ROSIDL_RUNTIME_C__PRIMITIVES_SEQUENCE_H_
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#define ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(NAME, TYPE) \
  typedef struct rosidl_runtime_c__ ## NAME ## __Sequence \
  { \
    TYPE * data; \
    size_t size; \
    size_t capacity; \
  } rosidl_runtime_c__ ## NAME ## __Sequence;
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(float, float)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(double, double)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(long_double, long double)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(char, signed char)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(wchar, uint16_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(boolean, bool)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(octet, uint8_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(uint8, uint8_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(int8, int8_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(uint16, uint16_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(int16, int16_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(uint32, uint32_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(int32, int32_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(uint64, uint64_t)
ESPDOCK_DOUBLE_PRIMITIVE_SEQUENCE(int64, int64_t)
#endif
