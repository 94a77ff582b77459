#pragma once

#include <stdbool.h>
#include <stdint.h>

/* Whether the LED is on at STEP (100 ms steps) of PATTERN, a bit mask read from bit 0, LENGTH steps long. */
bool blink_pattern_on(uint32_t pattern, uint8_t length, uint32_t step);
