/* Test double of ESP-IDF v5.3.5 esp_timer.h: the declarations espdock_transport.c uses. */
#pragma once
#include <stdint.h>
int64_t esp_timer_get_time(void);
