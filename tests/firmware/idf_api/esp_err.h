/* Test double of ESP-IDF v5.3.5 esp_err.h: the declarations espdock_transport.c uses. */
#pragma once
#include <stdint.h>
typedef int esp_err_t;
#define ESP_OK 0
#define ESP_FAIL -1
const char *esp_err_to_name(esp_err_t code);
