/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW__INIT_OPTIONS_H_
#define RMW__INIT_OPTIONS_H_
#include "rmw/types.h"
#endif
