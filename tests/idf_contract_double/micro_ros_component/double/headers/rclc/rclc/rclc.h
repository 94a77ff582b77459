/* contract double: stands in for the micro-ROS (jazzy) header of the same path, because
 * the micro-ROS sources cannot be fetched here. Only the names espdock firmware uses exist;
 * nothing implements them (no firmware is linked by the double). */
#ifndef RCLC__RCLC_H_
#define RCLC__RCLC_H_
#include "rclc/init.h"
#include "rclc/node.h"
#include "rclc/publisher.h"
#include "rclc/service.h"
#include "rclc/subscription.h"
#include "rclc/timer.h"
#include "rclc/types.h"
#endif
