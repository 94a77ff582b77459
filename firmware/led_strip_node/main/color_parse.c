/* Strict hex colour parsing; see color_parse.h. No ESP-IDF or micro-ROS includes. */
#include "color_parse.h"

#define SHORT_FORM_LEN 4u   /* "#RGB" */
#define LONG_FORM_LEN 7u    /* "#RRGGBB" */

/* Own digit decoder: strtol() would accept "0x", signs and spaces, and
 * isxdigit() depends on the C locale. */
static int hex_value(char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1;
}

static bool all_hex(const char *digits, size_t count)
{
    for (size_t i = 0; i < count; i++) {
        if (hex_value(digits[i]) < 0) {
            return false;
        }
    }
    return true;
}

static uint8_t short_channel(char digit)
{
    int v = hex_value(digit);
    return (uint8_t)(v * 16 + v);
}

static uint8_t long_channel(const char *pair)
{
    return (uint8_t)(hex_value(pair[0]) * 16 + hex_value(pair[1]));
}

color_status_t color_parse_hex(const char *text, size_t len, rgb8_t *out)
{
    if (text == NULL || out == NULL) {
        return COLOR_ERR_NULL;
    }
    if (len != SHORT_FORM_LEN && len != LONG_FORM_LEN) {
        return COLOR_ERR_LENGTH;
    }
    if (text[0] != '#') {
        return COLOR_ERR_PREFIX;
    }
    if (!all_hex(text + 1, len - 1)) {
        return COLOR_ERR_DIGIT;
    }
    if (len == SHORT_FORM_LEN) {
        out->r = short_channel(text[1]);
        out->g = short_channel(text[2]);
        out->b = short_channel(text[3]);
    } else {
        out->r = long_channel(text + 1);
        out->g = long_channel(text + 3);
        out->b = long_channel(text + 5);
    }
    return COLOR_OK;
}

const char *color_status_name(color_status_t status)
{
    switch (status) {
    case COLOR_OK:
        return "ok";
    case COLOR_ERR_NULL:
        return "no input";
    case COLOR_ERR_LENGTH:
        return "length is not 4 (#RGB) or 7 (#RRGGBB)";
    case COLOR_ERR_PREFIX:
        return "does not start with '#'";
    case COLOR_ERR_DIGIT:
        return "not a hex digit after '#'";
    default:
        return "unknown";
    }
}

bool color_equal(rgb8_t a, rgb8_t b)
{
    return a.r == b.r && a.g == b.g && a.b == b.b;
}

float color_channel_to_unit(uint8_t channel)
{
    return (float)channel / 255.0f;
}
