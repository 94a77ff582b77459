# micro_ros_espidf_component, prebuilt: links the libmicroros.a built once in
# the image. Unlike upstream's CMakeLists it never runs libmicroros.mk and
# registers no clean targets, so an app build can neither rebuild nor wipe it.
#
# Network interfaces: upstream compiles only network_interfaces/uros_wlan_netif.c
# unless BUILD_ETHERNET_INTERFACE is set. Here the app's Kconfig choice decides:
# WLAN or Ethernet, and neither for a custom (e.g. serial) transport. Sources may
# follow Kconfig, requirements may not: IDF reads REQUIRES before any sdkconfig
# exists (its "early expansion"). So the drivers the Ethernet interface includes
# (driver/gpio.h, driver/spi_master.h; IDF >= 5.3 splits them into
# esp_driver_gpio and esp_driver_spi, which none of the public requirements
# below export) are private requirements whatever is chosen; unused, they add
# nothing to the linked app.
set(netif_srcs "")
if(CONFIG_MICRO_ROS_ESP_NETIF_WLAN)
  list(APPEND netif_srcs "network_interfaces/uros_wlan_netif.c")
elseif(CONFIG_MICRO_ROS_ESP_NETIF_ENET)
  list(APPEND netif_srcs "network_interfaces/uros_ethernet_netif.c")
endif()
idf_component_register(SRCS ${netif_srcs}
                       INCLUDE_DIRS "network_interfaces"
                       REQUIRES nvs_flash esp_wifi esp_eth lwip
                       PRIV_REQUIRES esp_driver_gpio esp_driver_spi)

add_prebuilt_library(libmicroros-prebuilt "${COMPONENT_DIR}/libmicroros.a" REQUIRES lwip)
# Headers install as include/<pkg>/<pkg>/..., so each package dir is an include root.
target_include_directories(libmicroros-prebuilt INTERFACE "${COMPONENT_DIR}/include")
file(GLOB package_include_dirs LIST_DIRECTORIES true "${COMPONENT_DIR}/include/*")
foreach(dir ${package_include_dirs})
  if(IS_DIRECTORY "${dir}")
    target_include_directories(libmicroros-prebuilt INTERFACE "${dir}")
  endif()
endforeach()
target_link_libraries(${COMPONENT_LIB} INTERFACE libmicroros-prebuilt)
