/* Test double of rmw/init_options.h (ros2/rmw jazzy): an opaque init options type. */
#pragma once
typedef struct rmw_init_options_s {
    void *impl;
} rmw_init_options_t;
