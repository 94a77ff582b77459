/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_TYPESUPPORT_INTERFACE__MACROS_H_
#define ROSIDL_TYPESUPPORT_INTERFACE__MACROS_H_
#define ROSIDL_TYPESUPPORT_INTERFACE__MESSAGE_SYMBOL_NAME(typesupport_name, package_name, interface_type, interface_name) \
  typesupport_name ## __get_message_type_support_handle__ ## package_name ## __ ## interface_type ## __ ## interface_name
#define ROSIDL_TYPESUPPORT_INTERFACE__SERVICE_SYMBOL_NAME(typesupport_name, package_name, interface_type, interface_name) \
  typesupport_name ## __get_service_type_support_handle__ ## package_name ## __ ## interface_type ## __ ## interface_name
#endif
