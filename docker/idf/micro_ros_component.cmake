# micro_ros_espidf_component, prebuilt: links the libmicroros.a built once in
# the image. Unlike upstream's CMakeLists it never runs libmicroros.mk and
# registers no clean targets, so an app build can neither rebuild nor wipe it.
file(GLOB netif_srcs "${CMAKE_CURRENT_LIST_DIR}/network_interfaces/*.c")
idf_component_register(SRCS ${netif_srcs}
                       INCLUDE_DIRS "network_interfaces"
                       REQUIRES nvs_flash esp_wifi esp_eth lwip)

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
