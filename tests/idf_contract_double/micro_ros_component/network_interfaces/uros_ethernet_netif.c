/* contract double: stands in for micro_ros_espidf_component's
 * network_interfaces/uros_ethernet_netif.c (jazzy), because the micro-ROS sources cannot be
 * fetched here. A stub with upstream's include structure, which is what matters to a build:
 * upstream includes driver/gpio.h (component esp_driver_gpio in IDF 5.3) before, and outside,
 * its CONFIG_MICRO_ROS_ESP_NETIF_ENET guard, so compiling this file at all needs that
 * component among the micro-ROS component's requirements. */
#include <stdio.h>
#include <string.h>
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"
#include "esp_netif.h"
#include "esp_eth.h"
#include "esp_event.h"
#include "esp_log.h"
#include "driver/gpio.h"
#include "sdkconfig.h"
#if CONFIG_ETH_USE_SPI_ETHERNET
#include "driver/spi_master.h"
#endif
#include "uros_network_interfaces.h"

#ifdef CONFIG_MICRO_ROS_ESP_NETIF_ENET

esp_err_t uros_network_interface_initialize(void)
{
    return ESP_OK;
}

#endif
