#include "blink_pattern.h"
#include "driver/gpio.h"
#include "freertos/FreeRTOS.h"
#include "freertos/task.h"

#define LED_GPIO GPIO_NUM_2
#define HEARTBEAT 0x5u /* on, off, on, off, off */

void app_main(void)
{
    gpio_reset_pin(LED_GPIO);
    gpio_set_direction(LED_GPIO, GPIO_MODE_OUTPUT);
    for (uint32_t step = 0;; ++step) {
        gpio_set_level(LED_GPIO, blink_pattern_on(HEARTBEAT, 5, step));
        vTaskDelay(pdMS_TO_TICKS(100));
    }
}
