#include "blink_pattern.h"

bool blink_pattern_on(uint32_t pattern, uint8_t length, uint32_t step)
{
    if (length == 0 || length > 32) {
        return false;
    }
    return (pattern >> (step % length)) & 1u;
}
