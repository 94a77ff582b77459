/* Host tests for firmware/camera_node/main/camera_config.c */
#include <limits.h>
#include <string.h>

#include "camera_config.h"
#include "testkit.h"

/* Same field names as the rosidl-generated custom_interface__msg__CameraConfig:
 * proves the X-macro copy the app uses compiles against such a struct. */
typedef struct {
    uint8_t framesize;
    uint8_t quality;
    int8_t brightness;
    int8_t contrast;
    int8_t saturation;
    int8_t sharpness;
    uint8_t denoise;
    uint8_t special_effect;
    uint8_t wb_mode;
    uint8_t awb;
    uint8_t awb_gain;
    uint8_t aec;
    uint8_t aec2;
    int8_t ae_level;
    uint16_t aec_value;
    uint8_t agc;
    uint8_t agc_gain;
    uint8_t gainceiling;
    uint8_t bpc;
    uint8_t wpc;
    uint8_t raw_gma;
    uint8_t lenc;
    uint8_t hmirror;
    uint8_t vflip;
    uint8_t dcw;
    uint8_t colorbar;
    uint8_t pixformat;
} fake_rosidl_camera_config_t;

/* A configuration inside every range, with no field at a bound, so that
 * moving one field to a bound is the only change a test makes. */
static cam_cfg_t mid_config(void)
{
    cam_cfg_t c;
    memset(&c, 0, sizeof c);
    c.framesize = 6;
    c.quality = 12;
    c.denoise = 10;
    c.special_effect = 2;
    c.wb_mode = 2;
    c.ae_level = 0;
    c.aec_value = 300;
    c.agc_gain = 5;
    c.gainceiling = 2;
    c.pixformat = CAM_PIXFORMAT_JPEG;
    return c;
}

typedef struct {
    int type_min;
    int type_max;
} type_span_t;

/* Range of the field's C type, to know which of min-1 / max+1 is representable. */
static type_span_t field_type_span(cam_field_t field)
{
    type_span_t span = {0, UINT8_MAX};
    switch (field) {
    case CAM_FIELD_BRIGHTNESS:
    case CAM_FIELD_CONTRAST:
    case CAM_FIELD_SATURATION:
    case CAM_FIELD_SHARPNESS:
    case CAM_FIELD_AE_LEVEL:
        span.type_min = INT8_MIN;
        span.type_max = INT8_MAX;
        break;
    case CAM_FIELD_AEC_VALUE:
        span.type_max = UINT16_MAX;
        break;
    default:
        break;
    }
    return span;
}

static void expect_valid(cam_field_t field, int32_t value, uint8_t max_framesize)
{
    cam_cfg_t c = mid_config();
    cam_cfg_set(&c, field, value);
    cam_field_t bad = CAM_FIELD_COUNT;
    TK_CHECK(cam_cfg_validate(&c, max_framesize, &bad), "%s=%d rejected (bad=%d)",
             cam_field_info(field)->name, (int)value, (int)bad);
}

static void expect_invalid(cam_field_t field, int32_t value, uint8_t max_framesize)
{
    cam_cfg_t c = mid_config();
    cam_cfg_set(&c, field, value);
    TK_CHECK_EQ_INT(cam_cfg_get(&c, field), value, "value representable in the field type");
    cam_field_t bad = CAM_FIELD_COUNT;
    TK_CHECK(!cam_cfg_validate(&c, max_framesize, &bad), "%s=%d accepted",
             cam_field_info(field)->name, (int)value);
    TK_CHECK(bad == field, "%s=%d blamed field %d", cam_field_info(field)->name, (int)value, (int)bad);
}

static void test_table_matches_message(void)
{
    static const struct {
        const char *name;
        int32_t min;
        int32_t max;
    } expected[] = {
        {"framesize", 0, 15}, {"quality", 0, 63}, {"brightness", -2, 2}, {"contrast", -2, 2},
        {"saturation", -2, 2}, {"sharpness", -2, 2}, {"denoise", 0, 255}, {"special_effect", 0, 6},
        {"wb_mode", 0, 4}, {"awb", 0, 1}, {"awb_gain", 0, 1}, {"aec", 0, 1}, {"aec2", 0, 1},
        {"ae_level", -2, 2}, {"aec_value", 0, 1200}, {"agc", 0, 1}, {"agc_gain", 0, 30},
        {"gainceiling", 0, 6}, {"bpc", 0, 1}, {"wpc", 0, 1}, {"raw_gma", 0, 1}, {"lenc", 0, 1},
        {"hmirror", 0, 1}, {"vflip", 0, 1}, {"dcw", 0, 1}, {"colorbar", 0, 1}, {"pixformat", 0, 8},
    };
    TK_CHECK_EQ_INT(CAM_FIELD_COUNT, sizeof expected / sizeof expected[0], "field count");
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        const cam_field_info_t *info = cam_field_info((cam_field_t)i);
        TK_CHECK(info != NULL && strcmp(info->name, expected[i].name) == 0, "field %d name", i);
        TK_CHECK(info != NULL && info->min == expected[i].min && info->max == expected[i].max,
                 "%s range", expected[i].name);
        TK_CHECK(info != NULL && info->writable == (i != (int)CAM_FIELD_PIXFORMAT), "%s writability",
                 expected[i].name);
    }
    TK_CHECK(cam_field_info(CAM_FIELD_COUNT) == NULL, "past-the-end field has no info");
    TK_CHECK(cam_field_info((cam_field_t)-1) == NULL, "negative field has no info");
}

static void test_every_field_at_and_past_bounds(void)
{
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        cam_field_t field = (cam_field_t)i;
        const cam_field_info_t *info = cam_field_info(field);
        type_span_t span = field_type_span(field);
        expect_valid(field, info->min, CAM_FRAMESIZE_UXGA);
        expect_valid(field, info->max, CAM_FRAMESIZE_UXGA);
        if (info->min - 1 >= span.type_min) {
            expect_invalid(field, info->min - 1, CAM_FRAMESIZE_UXGA);
        }
        if (info->max + 1 <= span.type_max) {
            expect_invalid(field, info->max + 1, CAM_FRAMESIZE_UXGA);
        }
        /* The extremes of the type are the cases a fuzzing client hits first. */
        if (span.type_min < info->min) {
            expect_invalid(field, span.type_min, CAM_FRAMESIZE_UXGA);
        }
        if (span.type_max > info->max) {
            expect_invalid(field, span.type_max, CAM_FRAMESIZE_UXGA);
        }
    }
}

static void test_unrepresentable_bounds_are_the_type_limits(void)
{
    /* uint8 fields with min 0 cannot go below it; denoise's max is the type's. */
    cam_cfg_t c = mid_config();
    cam_cfg_set(&c, CAM_FIELD_DENOISE, 256);
    TK_CHECK_EQ_INT(c.denoise, 0, "256 wraps in a uint8 field (range check cannot see it)");
    cam_cfg_set(&c, CAM_FIELD_QUALITY, -1);
    TK_CHECK_EQ_INT(c.quality, 255, "-1 wraps to 255 in a uint8 field");
    TK_CHECK(!cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, NULL), "wrapped quality 255 is out of range");
}

static void test_framesize_limit(void)
{
    TK_CHECK_EQ_INT(cam_cfg_framesize_limit(10), 10, "limit below the message max");
    TK_CHECK_EQ_INT(cam_cfg_framesize_limit(15), 15, "limit at the message max");
    TK_CHECK_EQ_INT(cam_cfg_framesize_limit(200), 15, "limit never above the message max");
    /* The node allows frames only up to the size its buffers and stream were sized for. */
    expect_valid(CAM_FIELD_FRAMESIZE, 10, 10);
    expect_invalid(CAM_FIELD_FRAMESIZE, 11, 10);
    expect_valid(CAM_FIELD_FRAMESIZE, 0, 10);
    expect_valid(CAM_FIELD_FRAMESIZE, CAM_FRAMESIZE_QVGA, CAM_FRAMESIZE_QVGA);
    expect_invalid(CAM_FIELD_FRAMESIZE, CAM_FRAMESIZE_QVGA + 1, CAM_FRAMESIZE_QVGA);
}

static void test_first_bad_field_reported_and_null_allowed(void)
{
    cam_cfg_t c = mid_config();
    c.contrast = 5;
    c.colorbar = 2;
    cam_field_t bad = CAM_FIELD_COUNT;
    TK_CHECK(!cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, &bad), "two bad fields");
    TK_CHECK(bad == CAM_FIELD_CONTRAST, "first offender in message order, got %d", (int)bad);
    TK_CHECK(!cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, NULL), "NULL bad_field pointer is fine");
    c = mid_config();
    bad = CAM_FIELD_COUNT;
    TK_CHECK(cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, &bad), "mid config valid");
    TK_CHECK(bad == CAM_FIELD_COUNT, "bad_field untouched when valid");
}

static void test_get_set_round_trip(void)
{
    cam_cfg_t c;
    memset(&c, 0, sizeof c);
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        const cam_field_info_t *info = cam_field_info((cam_field_t)i);
        cam_cfg_set(&c, (cam_field_t)i, info->max);
        TK_CHECK_EQ_INT(cam_cfg_get(&c, (cam_field_t)i), info->max, info->name);
        cam_cfg_set(&c, (cam_field_t)i, info->min);
        TK_CHECK_EQ_INT(cam_cfg_get(&c, (cam_field_t)i), info->min, info->name);
    }
    TK_CHECK_EQ_INT(cam_cfg_get(&c, CAM_FIELD_COUNT), 0, "invalid field reads as 0");
    cam_cfg_t before = c;
    cam_cfg_set(&c, CAM_FIELD_COUNT, 7);
    TK_CHECK(memcmp(&before, &c, sizeof c) == 0, "invalid field write changes nothing");
}

static void test_xmacro_copy_to_rosidl_shaped_struct(void)
{
    cam_cfg_t src = mid_config();
    src.brightness = -2;
    src.aec_value = 1200;
    src.colorbar = 1;
    fake_rosidl_camera_config_t msg;
    memset(&msg, 0xff, sizeof msg);
    fake_rosidl_camera_config_t *dst_msg = &msg;
    const cam_cfg_t *src_cfg = &src;
#define COPY_TO_MSG(name, ...) dst_msg->name = src_cfg->name;
    CAM_CFG_FIELDS(COPY_TO_MSG)
#undef COPY_TO_MSG
    TK_CHECK_EQ_INT(msg.brightness, -2, "brightness copied");
    TK_CHECK_EQ_INT(msg.aec_value, 1200, "aec_value copied");
    TK_CHECK_EQ_INT(msg.pixformat, CAM_PIXFORMAT_JPEG, "pixformat copied");
    cam_cfg_t back;
    memset(&back, 0, sizeof back);
    cam_cfg_t *dst_cfg = &back;
    const fake_rosidl_camera_config_t *src_msg = &msg;
#define COPY_FROM_MSG(name, ...) dst_cfg->name = src_msg->name;
    CAM_CFG_FIELDS(COPY_FROM_MSG)
#undef COPY_FROM_MSG
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        TK_CHECK_EQ_INT(cam_cfg_get(&back, (cam_field_t)i), cam_cfg_get(&src, (cam_field_t)i),
                        cam_field_info((cam_field_t)i)->name);
    }
}

/* Fake sensor: records setter calls and can refuse chosen fields. */
typedef struct {
    cam_cfg_t state;
    int calls;
    cam_field_t order[CAM_FIELD_COUNT];
    int times_called[CAM_FIELD_COUNT];
    bool refuse[CAM_FIELD_COUNT];
} fake_sensor_t;

static int fake_setter(void *ctx, cam_field_t field, int32_t value)
{
    fake_sensor_t *s = ctx;
    if (s->calls < (int)CAM_FIELD_COUNT) {
        s->order[s->calls] = field;
    }
    s->calls++;
    s->times_called[field]++;
    if (s->refuse[field]) {
        return -1;
    }
    cam_cfg_set(&s->state, field, value);
    return 0;
}

static void fake_sensor_init(fake_sensor_t *s, cam_cfg_t state)
{
    memset(s, 0, sizeof *s);
    s->state = state;
}

static int position_of(const fake_sensor_t *s, cam_field_t field)
{
    for (int i = 0; i < s->calls && i < (int)CAM_FIELD_COUNT; i++) {
        if (s->order[i] == field) {
            return i;
        }
    }
    return -1;
}

static void test_diff_applies_nothing_when_equal(void)
{
    fake_sensor_t s;
    fake_sensor_init(&s, mid_config());
    cam_cfg_t wanted = mid_config();
    cam_apply_result_t r = cam_cfg_apply_diff(&s.state, &wanted, fake_setter, &s);
    TK_CHECK_EQ_INT(s.calls, 0, "no setter call for an identical request");
    TK_CHECK_EQ_INT(r.applied, 0, "applied");
    TK_CHECK_EQ_INT(r.failed, 0, "failed");
    TK_CHECK(r.first_failure == CAM_FIELD_COUNT, "no failure recorded");
}

static void test_diff_applies_only_differing_fields(void)
{
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        cam_field_t field = (cam_field_t)i;
        const cam_field_info_t *info = cam_field_info(field);
        fake_sensor_t s;
        fake_sensor_init(&s, mid_config());
        cam_cfg_t current = s.state;
        cam_cfg_t wanted = current;
        int32_t other = cam_cfg_get(&current, field) == info->max ? info->min : info->max;
        cam_cfg_set(&wanted, field, other);
        cam_apply_result_t r = cam_cfg_apply_diff(&current, &wanted, fake_setter, &s);
        if (info->writable) {
            TK_CHECK_EQ_INT(s.calls, 1, info->name);
            TK_CHECK(s.times_called[field] == 1, "%s setter called once", info->name);
            TK_CHECK_EQ_INT(cam_cfg_get(&s.state, field), other, info->name);
            TK_CHECK_EQ_INT(r.applied, 1, info->name);
        } else {
            /* pixformat is read-only: the JPEG stream stays JPEG. */
            TK_CHECK_EQ_INT(s.calls, 0, info->name);
            TK_CHECK_EQ_INT(r.applied, 0, info->name);
        }
    }
}

static void test_diff_covers_every_writable_field_once_in_order(void)
{
    fake_sensor_t s;
    cam_cfg_t current;
    memset(&current, 0, sizeof current);
    fake_sensor_init(&s, current);
    cam_cfg_t wanted;
    memset(&wanted, 0, sizeof wanted);
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        cam_cfg_set(&wanted, (cam_field_t)i, cam_field_info((cam_field_t)i)->max);
    }
    cam_apply_result_t r = cam_cfg_apply_diff(&current, &wanted, fake_setter, &s);
    TK_CHECK_EQ_INT(s.calls, CAM_FIELD_COUNT - 1, "every writable field, once");
    TK_CHECK_EQ_INT(r.applied, CAM_FIELD_COUNT - 1, "all applied");
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        int want_calls = i == (int)CAM_FIELD_PIXFORMAT ? 0 : 1;
        TK_CHECK_EQ_INT(s.times_called[i], want_calls, cam_field_info((cam_field_t)i)->name);
    }
    TK_CHECK_EQ_INT(position_of(&s, CAM_FIELD_FRAMESIZE), 0, "frame size goes first");
    TK_CHECK(position_of(&s, CAM_FIELD_AEC) < position_of(&s, CAM_FIELD_AEC_VALUE),
             "exposure mode before manual exposure");
    TK_CHECK(position_of(&s, CAM_FIELD_AGC) < position_of(&s, CAM_FIELD_AGC_GAIN),
             "gain mode before manual gain");
    TK_CHECK(position_of(&s, CAM_FIELD_AWB) < position_of(&s, CAM_FIELD_AWB_GAIN),
             "white balance mode before its gain");
    TK_CHECK(position_of(&s, CAM_FIELD_AWB) < position_of(&s, CAM_FIELD_WB_MODE),
             "white balance mode before wb_mode");
}

static void test_diff_continues_after_a_refused_field(void)
{
    fake_sensor_t s;
    fake_sensor_init(&s, mid_config());
    s.refuse[CAM_FIELD_SHARPNESS] = true;   /* OV2640 has no sharpness control */
    s.refuse[CAM_FIELD_DENOISE] = true;
    cam_cfg_t current = s.state;
    cam_cfg_t wanted = current;
    wanted.sharpness = 1;
    wanted.denoise = 20;
    wanted.vflip = 1;
    wanted.quality = 10;
    cam_apply_result_t r = cam_cfg_apply_diff(&current, &wanted, fake_setter, &s);
    TK_CHECK_EQ_INT(s.calls, 4, "all four differing fields attempted");
    TK_CHECK_EQ_INT(r.applied, 2, "vflip and quality applied");
    TK_CHECK_EQ_INT(r.failed, 2, "sharpness and denoise refused");
    TK_CHECK(r.first_failure == CAM_FIELD_SHARPNESS, "first failure is sharpness, got %d",
             (int)r.first_failure);
    TK_CHECK_EQ_INT(s.state.vflip, 1, "vflip reached the sensor");
    TK_CHECK_EQ_INT(s.state.quality, 10, "quality reached the sensor");
    TK_CHECK_EQ_INT(s.state.sharpness, 0, "refused sharpness unchanged");
}

/* Buffers hold width*height/5 bytes of the largest frame: a frame that fills them may not ask for
 * the lowest qualities (its JPEG would overflow), a smaller frame may in proportion. */
static void test_quality_is_bounded_by_the_frame_s_share_of_the_buffer(void)
{
    TK_CHECK_EQ_INT(cam_cfg_quality_min(CAM_FRAMESIZE_UXGA, CAM_FRAMESIZE_UXGA), CAM_QUALITY_FLOOR, "full frame");
    TK_CHECK_EQ_INT(cam_cfg_quality_min(CAM_FRAMESIZE_QVGA, CAM_FRAMESIZE_UXGA), 0, "QVGA is 4 %% of UXGA");
    TK_CHECK_EQ_INT(cam_cfg_quality_min(10, 12), 3, "VGA in XGA buffers: 39 %% of the pixels");
    TK_CHECK_EQ_INT(cam_cfg_quality_min(CAM_FRAMESIZE_QVGA, CAM_FRAMESIZE_QVGA), CAM_QUALITY_FLOOR, "QVGA alone");
    cam_cfg_t c = mid_config();
    c.framesize = CAM_FRAMESIZE_UXGA;
    c.quality = CAM_QUALITY_FLOOR - 1;
    cam_field_t bad = CAM_FIELD_COUNT;
    TK_CHECK(!cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, &bad), "quality 9 at the full buffer accepted");
    TK_CHECK(bad == CAM_FIELD_QUALITY, "blamed field %d, not quality", (int)bad);
    c.quality = CAM_QUALITY_FLOOR;
    TK_CHECK(cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, NULL), "quality 10 at the full buffer rejected");
    c.framesize = CAM_FRAMESIZE_QVGA;
    c.quality = 0;
    TK_CHECK(cam_cfg_validate(&c, CAM_FRAMESIZE_UXGA, NULL), "quality 0 for QVGA in UXGA buffers rejected");
    TK_CHECK(!cam_cfg_validate(&c, CAM_FRAMESIZE_QVGA, NULL), "quality 0 at the full QVGA buffer accepted");
}

int main(void)
{
    test_quality_is_bounded_by_the_frame_s_share_of_the_buffer();
    test_table_matches_message();
    test_every_field_at_and_past_bounds();
    test_unrepresentable_bounds_are_the_type_limits();
    test_framesize_limit();
    test_first_bad_field_reported_and_null_allowed();
    test_get_set_round_trip();
    test_xmacro_copy_to_rosidl_shaped_struct();
    test_diff_applies_nothing_when_equal();
    test_diff_applies_only_differing_fields();
    test_diff_covers_every_writable_field_once_in_order();
    test_diff_continues_after_a_refused_field();
    return tk_report("camera_config");
}
