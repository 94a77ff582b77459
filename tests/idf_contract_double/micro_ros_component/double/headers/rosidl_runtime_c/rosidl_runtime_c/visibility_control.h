/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__VISIBILITY_CONTROL_H_
#define ROSIDL_RUNTIME_C__VISIBILITY_CONTROL_H_
#define ROSIDL_GENERATOR_C_PUBLIC
#define ROSIDL_GENERATOR_C_EXPORT
#define ROSIDL_GENERATOR_C_IMPORT
#define ROSIDL_TYPESUPPORT_INTERFACE_PUBLIC
#endif
