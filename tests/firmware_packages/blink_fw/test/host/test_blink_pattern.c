#include <stdio.h>
#include <string.h>

#include "blink_pattern.h"

static int heartbeat(void)
{
    const int expected[] = {1, 0, 1, 0, 0, 1};
    for (unsigned step = 0; step < 6; ++step) {
        if (blink_pattern_on(0x5u, 5, step) != expected[step]) {
            printf("step %u: expected %d\n", step, expected[step]);
            return 1;
        }
    }
    return 0;
}

static int bad_length(void)
{
    return blink_pattern_on(0xffffffffu, 0, 3) || blink_pattern_on(0xffffffffu, 33, 3);
}

int main(int argc, char **argv)
{
    if (argc == 2 && strcmp(argv[1], "heartbeat") == 0) {
        return heartbeat();
    }
    if (argc == 2 && strcmp(argv[1], "bad_length") == 0) {
        return bad_length();
    }
    return 2;
}
