/* contract double only (no upstream counterpart): what a generated typesupport handle of the
 * micro-ROS double points at, so tests can see which fields a type was generated with. */
#ifndef ESPDOCK_DOUBLE__TYPE_DESCRIPTION_H_
#define ESPDOCK_DOUBLE__TYPE_DESCRIPTION_H_
#include <stddef.h>
typedef struct espdock_double__type_description_t
{
  const char * name;
  size_t field_count;
  const char * const * fields;
} espdock_double__type_description_t;
#endif
