/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef MICRO_ROS_UTILITIES__TYPE_UTILITIES_H_
#define MICRO_ROS_UTILITIES__TYPE_UTILITIES_H_
#include <stdbool.h>
#include <stddef.h>
#include "rcutils/allocator.h"
#include "rosidl_runtime_c/message_type_support_struct.h"
typedef struct micro_ros_utilities_memory_conf_t
{
  size_t max_string_capacity;
  size_t max_ros2_type_sequence_capacity;
  size_t max_basic_type_sequence_capacity;
  const void * rules;
  size_t n_rules;
  const rcutils_allocator_t * allocator;
} micro_ros_utilities_memory_conf_t;
bool micro_ros_utilities_create_message_memory(const rosidl_message_type_support_t * type_support,
  void * ros2_msg, const micro_ros_utilities_memory_conf_t conf);
bool micro_ros_utilities_destroy_message_memory(const rosidl_message_type_support_t * type_support,
  void * ros2_msg, const micro_ros_utilities_memory_conf_t conf);
#endif
