/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCL__ERROR_HANDLING_H_
#define RCL__ERROR_HANDLING_H_
void rcl_reset_error(void);
#endif
