/* contract double: stands in for micro_ros_espidf_component's
 * network_interfaces/uros_network_interfaces.h, because the micro-ROS sources cannot be
 * fetched here. Same declaration as upstream. */
#ifndef UROS_NETWORK_INTERFACES_H
#define UROS_NETWORK_INTERFACES_H

#include "esp_err.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Bring up the network interface Kconfig selects (Wi-Fi station here). */
esp_err_t uros_network_interface_initialize(void);

#ifdef __cplusplus
}
#endif

#endif
