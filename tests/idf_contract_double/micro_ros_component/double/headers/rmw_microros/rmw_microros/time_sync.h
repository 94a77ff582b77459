/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RMW_MICROROS__TIME_SYNC_H_
#define RMW_MICROROS__TIME_SYNC_H_
#include <stdbool.h>
#include <stdint.h>
#include "rmw/types.h"
rmw_ret_t rmw_uros_sync_session(const int timeout_ms);
bool rmw_uros_epoch_synchronized(void);
int64_t rmw_uros_epoch_millis(void);
int64_t rmw_uros_epoch_nanos(void);
#endif
