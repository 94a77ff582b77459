/*
 * Strict hex colour parsing for the LED strip node (hardware-free, host-tested).
 *
 * Accepted: exactly "#RGB" or "#RRGGBB", hex digits of either case. "#RGB"
 * expands each digit (so "#1af" is "#11aaff", as in CSS). Anything else,
 * including surrounding whitespace, is rejected: a QR code that is not a
 * colour must leave the strip alone instead of turning its ASCII codes into
 * one (the seed's parser did that).
 */
#ifndef COLOR_PARSE_H
#define COLOR_PARSE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    uint8_t r;
    uint8_t g;
    uint8_t b;
} rgb8_t;

typedef enum {
    COLOR_OK = 0,
    COLOR_ERR_NULL,     /* no text or no output */
    COLOR_ERR_LENGTH,   /* not 4 or 7 characters */
    COLOR_ERR_PREFIX,   /* does not start with '#' */
    COLOR_ERR_DIGIT,    /* a character after '#' is not a hex digit (NUL included) */
} color_status_t;

/** Parses len bytes of text (no NUL needed; an embedded NUL is an error); writes out only on COLOR_OK. */
color_status_t color_parse_hex(const char *text, size_t len, rgb8_t *out);

/** Short description of a parse status, for logs. */
const char *color_status_name(color_status_t status);

/** True when both colours are the same. */
bool color_equal(rgb8_t a, rgb8_t b);

/** Scales one 0..255 channel to the 0..1 float range of std_msgs/ColorRGBA. */
float color_channel_to_unit(uint8_t channel);

#ifdef __cplusplus
}
#endif

#endif /* COLOR_PARSE_H */
