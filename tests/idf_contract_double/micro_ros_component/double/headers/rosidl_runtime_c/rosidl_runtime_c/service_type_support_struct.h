/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef ROSIDL_RUNTIME_C__SERVICE_TYPE_SUPPORT_STRUCT_H_
#define ROSIDL_RUNTIME_C__SERVICE_TYPE_SUPPORT_STRUCT_H_
#include "rosidl_runtime_c/message_type_support_struct.h"
typedef struct rosidl_service_type_support_t rosidl_service_type_support_t;
typedef const rosidl_service_type_support_t * (*rosidl_service_typesupport_handle_function)(
  const rosidl_service_type_support_t *, const char *);
struct rosidl_service_type_support_t
{
  const char * typesupport_identifier;
  const void * data;
  rosidl_service_typesupport_handle_function func;
  const rosidl_message_type_support_t * request_typesupport;
  const rosidl_message_type_support_t * response_typesupport;
};
#define ROSIDL_GET_SRV_TYPE_SUPPORT(PkgName, SrvSubfolder, SrvName) \
  ROSIDL_TYPESUPPORT_INTERFACE__SERVICE_SYMBOL_NAME( \
    rosidl_typesupport_c, PkgName, SrvSubfolder, SrvName)()
#endif
