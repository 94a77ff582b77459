/* Test double of FreeRTOS task.h (ESP-IDF v5.3.5): nothing espdock_transport.c calls. */
#pragma once
#include "freertos/FreeRTOS.h"
