/* contract double: stands in for micro_ros_espidf_component's
 * network_interfaces/uros_wlan_netif.c, because the micro-ROS sources cannot be fetched
 * here. A stub: the double never links or runs firmware. */
#include "sdkconfig.h"

#ifdef CONFIG_MICRO_ROS_ESP_NETIF_WLAN

#include "uros_network_interfaces.h"

esp_err_t uros_network_interface_initialize(void)
{
    return ESP_OK;
}

#endif
