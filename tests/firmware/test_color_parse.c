/* Host tests for firmware/led_strip_node/main/color_parse.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "color_parse.h"
#include "testkit.h"

/* Parses a copy in an exactly-sized heap block (no terminating NUL), so the
 * sanitizer build catches any read past len. */
static color_status_t parse_exact(const char *text, size_t len, rgb8_t *out)
{
    char *copy = malloc(len == 0u ? 1u : len);
    if (copy == NULL) {
        return COLOR_ERR_NULL;
    }
    memcpy(copy, text, len);
    color_status_t status = color_parse_hex(copy, len, out);
    free(copy);
    return status;
}

static void expect_color(const char *text, uint8_t r, uint8_t g, uint8_t b)
{
    rgb8_t c = {0, 0, 0};
    color_status_t status = parse_exact(text, strlen(text), &c);
    TK_CHECK(status == COLOR_OK, "'%s' rejected: %s", text, color_status_name(status));
    TK_CHECK(c.r == r && c.g == g && c.b == b, "'%s' -> (%u,%u,%u), want (%u,%u,%u)",
             text, c.r, c.g, c.b, r, g, b);
}

static void expect_reject(const char *text, size_t len, color_status_t want)
{
    rgb8_t sentinel = {1, 2, 3};
    color_status_t status = parse_exact(text, len, &sentinel);
    TK_CHECK(status == want, "'%.*s' (len %zu): got '%s', want '%s'", (int)len, text, len,
             color_status_name(status), color_status_name(want));
    TK_CHECK(sentinel.r == 1 && sentinel.g == 2 && sentinel.b == 3,
             "'%.*s' wrote the output although rejected", (int)len, text);
}

static void test_long_form(void)
{
    expect_color("#000000", 0x00, 0x00, 0x00);
    expect_color("#ffffff", 0xff, 0xff, 0xff);
    expect_color("#FFFFFF", 0xff, 0xff, 0xff);
    expect_color("#11aaff", 0x11, 0xaa, 0xff);
    expect_color("#12AbEf", 0x12, 0xab, 0xef);
    expect_color("#ff0000", 0xff, 0x00, 0x00);
    expect_color("#00ff00", 0x00, 0xff, 0x00);
    expect_color("#0000ff", 0x00, 0x00, 0xff);
    expect_color("#09afAF", 0x09, 0xaf, 0xaf);
}

static void test_short_form_expands_each_digit(void)
{
    expect_color("#1af", 0x11, 0xaa, 0xff);
    expect_color("#1AF", 0x11, 0xaa, 0xff);
    expect_color("#000", 0x00, 0x00, 0x00);
    expect_color("#fff", 0xff, 0xff, 0xff);
    expect_color("#f00", 0xff, 0x00, 0x00);
    expect_color("#09a", 0x00, 0x99, 0xaa);
    expect_color("#aBc", 0xaa, 0xbb, 0xcc);

    rgb8_t short_form = {0, 0, 0};
    rgb8_t long_form = {0, 0, 0};
    TK_CHECK(color_parse_hex("#1af", 4, &short_form) == COLOR_OK, "short form");
    TK_CHECK(color_parse_hex("#11aaff", 7, &long_form) == COLOR_OK, "long form");
    TK_CHECK(color_equal(short_form, long_form), "#1af and #11aaff differ");
}

static void test_every_hex_digit(void)
{
    const char *digits = "0123456789abcdefABCDEF";
    const int values[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 10, 11, 12, 13, 14, 15};
    for (size_t i = 0; i < strlen(digits); i++) {
        char text[5] = {'#', digits[i], digits[i], digits[i], '\0'};
        uint8_t v = (uint8_t)(values[i] * 17);
        expect_color(text, v, v, v);
    }
}

static void test_invalid_digits(void)
{
    expect_reject("#GGG", 4, COLOR_ERR_DIGIT);
    expect_reject("#ggg", 4, COLOR_ERR_DIGIT);
    expect_reject("#12345g", 7, COLOR_ERR_DIGIT);
    expect_reject("#g23456", 7, COLOR_ERR_DIGIT);
    expect_reject("#-12", 4, COLOR_ERR_DIGIT);        /* strtol would take a sign */
    expect_reject("#+12345", 7, COLOR_ERR_DIGIT);
    expect_reject("# 12", 4, COLOR_ERR_DIGIT);        /* nor leading blanks */
    expect_reject("#0x1234", 7, COLOR_ERR_DIGIT);     /* nor a 0x prefix */
    expect_reject("#12 456", 7, COLOR_ERR_DIGIT);
    expect_reject("##12", 4, COLOR_ERR_DIGIT);
    expect_reject("#:;<", 4, COLOR_ERR_DIGIT);        /* just past '9' in ASCII */
    expect_reject("#/@`", 4, COLOR_ERR_DIGIT);        /* just before '0', 'A', 'a' */
    expect_reject("#GHIJKL", 7, COLOR_ERR_DIGIT);
    expect_reject("#\xc3\xa9\x41", 4, COLOR_ERR_DIGIT); /* UTF-8 bytes */
}

static void test_invalid_lengths(void)
{
    expect_reject("", 0, COLOR_ERR_LENGTH);
    expect_reject("#", 1, COLOR_ERR_LENGTH);
    expect_reject("#1", 2, COLOR_ERR_LENGTH);
    expect_reject("#12", 3, COLOR_ERR_LENGTH);
    expect_reject("#1234", 5, COLOR_ERR_LENGTH);
    expect_reject("#12345", 6, COLOR_ERR_LENGTH);
    expect_reject("#1234567", 8, COLOR_ERR_LENGTH);
    expect_reject("#12345678", 9, COLOR_ERR_LENGTH);
    expect_reject("hello", 5, COLOR_ERR_LENGTH);
    expect_reject("#1af\n", 5, COLOR_ERR_LENGTH);     /* strict: no trailing newline */
    expect_reject(" #1af", 5, COLOR_ERR_LENGTH);
    expect_reject("#11aaff ", 8, COLOR_ERR_LENGTH);
}

static void test_invalid_prefix(void)
{
    expect_reject("1afe", 4, COLOR_ERR_PREFIX);
    expect_reject("11aaff0", 7, COLOR_ERR_PREFIX);
    expect_reject("hello!!", 7, COLOR_ERR_PREFIX);
    expect_reject(" #1a", 4, COLOR_ERR_PREFIX);
    expect_reject("\0#1a", 4, COLOR_ERR_PREFIX);
}

static void test_embedded_nul_and_length_mismatch(void)
{
    /* ROS strings carry a size; the parser must trust it, not strlen(). */
    expect_reject("#1a\0", 4, COLOR_ERR_DIGIT);
    expect_reject("#1\0f", 4, COLOR_ERR_DIGIT);
    expect_reject("#11aa\0f", 7, COLOR_ERR_DIGIT);
    expect_reject("#11aaff\0", 8, COLOR_ERR_LENGTH);
    /* A valid prefix inside a longer size is not a colour. */
    expect_reject("#1afXYZ", 7, COLOR_ERR_DIGIT);
    /* A shorter size than the C string: only the first len bytes count. */
    rgb8_t c = {0, 0, 0};
    TK_CHECK(color_parse_hex("#1af000", 4, &c) == COLOR_OK, "first 4 bytes are #1af");
    TK_CHECK(c.r == 0x11 && c.g == 0xaa && c.b == 0xff, "size-limited parse -> (%u,%u,%u)", c.r, c.g, c.b);
}

static void test_very_long_strings(void)
{
    size_t len = 1u << 16;
    char *text = malloc(len);
    TK_CHECK(text != NULL, "allocation");
    if (text == NULL) {
        return;
    }
    memset(text, 'f', len);
    text[0] = '#';
    expect_reject(text, len, COLOR_ERR_LENGTH);
    expect_reject(text, 1000, COLOR_ERR_LENGTH);
    /* An absurd size must be rejected before any byte past the buffer is read. */
    rgb8_t c = {1, 2, 3};
    TK_CHECK(color_parse_hex(text, SIZE_MAX, &c) == COLOR_ERR_LENGTH, "SIZE_MAX length");
    free(text);
}

static void test_null_arguments(void)
{
    rgb8_t c;
    TK_CHECK(color_parse_hex(NULL, 4, &c) == COLOR_ERR_NULL, "NULL text");
    TK_CHECK(color_parse_hex("#1af", 4, NULL) == COLOR_ERR_NULL, "NULL output");
    TK_CHECK(color_parse_hex(NULL, 0, NULL) == COLOR_ERR_NULL, "both NULL");
}

static void test_helpers(void)
{
    TK_CHECK(color_channel_to_unit(0) == 0.0f, "0 -> 0.0");
    TK_CHECK(color_channel_to_unit(255) == 1.0f, "255 -> 1.0");
    float mid = color_channel_to_unit(0x80);
    TK_CHECK(mid > 0.50f && mid < 0.51f, "0x80 -> %f", (double)mid);
    rgb8_t a = {1, 2, 3};
    rgb8_t b = {1, 2, 3};
    rgb8_t c = {1, 2, 4};
    TK_CHECK(color_equal(a, b), "equal colours");
    TK_CHECK(!color_equal(a, c), "different blue");
    TK_CHECK(strcmp(color_status_name(COLOR_OK), "ok") == 0, "status name");
    TK_CHECK(strcmp(color_status_name((color_status_t)99), "unknown") == 0, "unknown status name");
}

int main(void)
{
    test_long_form();
    test_short_form_expands_each_digit();
    test_every_hex_digit();
    test_invalid_digits();
    test_invalid_lengths();
    test_invalid_prefix();
    test_embedded_nul_and_length_mismatch();
    test_very_long_strings();
    test_null_arguments();
    test_helpers();
    return tk_report("color_parse");
}
