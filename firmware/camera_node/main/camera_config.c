/* Camera settings validation and diffing; see camera_config.h. No ESP-IDF or micro-ROS includes. */
#include "camera_config.h"

#include <stddef.h>

#define CAM_CFG_INFO_ROW(name, e, type, lo, hi, w) {#name, (lo), (hi), (w)},
static const cam_field_info_t FIELD_INFO[CAM_FIELD_COUNT] = {
    CAM_CFG_FIELDS(CAM_CFG_INFO_ROW)
};
#undef CAM_CFG_INFO_ROW

/*
 * Order in which differing fields reach the sensor: the frame size first
 * (it reprograms the sensor window), then the automatic modes, so that a
 * request switching auto exposure off and setting a manual value lands the
 * value after the mode change instead of being overwritten by the loop it
 * disables. The rest follows message order.
 */
static const cam_field_t APPLY_ORDER[] = {
    CAM_FIELD_FRAMESIZE,
    CAM_FIELD_AWB,
    CAM_FIELD_AEC,
    CAM_FIELD_AGC,
    CAM_FIELD_QUALITY,
    CAM_FIELD_BRIGHTNESS,
    CAM_FIELD_CONTRAST,
    CAM_FIELD_SATURATION,
    CAM_FIELD_SHARPNESS,
    CAM_FIELD_DENOISE,
    CAM_FIELD_SPECIAL_EFFECT,
    CAM_FIELD_WB_MODE,
    CAM_FIELD_AWB_GAIN,
    CAM_FIELD_AEC2,
    CAM_FIELD_AE_LEVEL,
    CAM_FIELD_AEC_VALUE,
    CAM_FIELD_AGC_GAIN,
    CAM_FIELD_GAINCEILING,
    CAM_FIELD_BPC,
    CAM_FIELD_WPC,
    CAM_FIELD_RAW_GMA,
    CAM_FIELD_LENC,
    CAM_FIELD_HMIRROR,
    CAM_FIELD_VFLIP,
    CAM_FIELD_DCW,
    CAM_FIELD_COLORBAR,
};

/* Every writable field (all but pixformat) appears exactly once above. */
typedef char apply_order_covers_writable_fields
    [(sizeof APPLY_ORDER / sizeof APPLY_ORDER[0] == CAM_FIELD_COUNT - 1) ? 1 : -1];

const cam_field_info_t *cam_field_info(cam_field_t field)
{
    if ((unsigned)field >= (unsigned)CAM_FIELD_COUNT) {
        return NULL;
    }
    return &FIELD_INFO[field];
}

int32_t cam_cfg_get(const cam_cfg_t *cfg, cam_field_t field)
{
    switch (field) {
#define CAM_CFG_GET_CASE(name, e, type, lo, hi, w) \
    case CAM_FIELD_##e:                          \
        return (int32_t)cfg->name;
        CAM_CFG_FIELDS(CAM_CFG_GET_CASE)
#undef CAM_CFG_GET_CASE
    default:
        return 0;
    }
}

void cam_cfg_set(cam_cfg_t *cfg, cam_field_t field, int32_t value)
{
    switch (field) {
#define CAM_CFG_SET_CASE(name, e, type, lo, hi, w) \
    case CAM_FIELD_##e:                          \
        cfg->name = (type)value;                 \
        break;
        CAM_CFG_FIELDS(CAM_CFG_SET_CASE)
#undef CAM_CFG_SET_CASE
    default:
        break;
    }
}

int32_t cam_cfg_framesize_limit(uint8_t max_framesize)
{
    int32_t msg_max = FIELD_INFO[CAM_FIELD_FRAMESIZE].max;
    return max_framesize < msg_max ? (int32_t)max_framesize : msg_max;
}

/* Pixels of each framesize_t 0..15, esp32-camera's driver/sensor.c resolution[] table. */
static const uint32_t FRAME_PIXELS[] = {
    96u * 96u, 160u * 120u, 128u * 128u, 176u * 144u, 240u * 176u, 240u * 240u,
    320u * 240u, 320u * 320u, 400u * 296u, 480u * 320u, 640u * 480u, 800u * 600u,
    1024u * 768u, 1280u * 720u, 1280u * 1024u, 1600u * 1200u,
};

int32_t cam_cfg_quality_min(uint8_t framesize, uint8_t max_framesize)
{
    uint8_t limit = (uint8_t)cam_cfg_framesize_limit(max_framesize);
    if (framesize > limit) {
        return CAM_QUALITY_FLOOR;
    }
    /* JPEG size grows about as 1/quality and with the pixel count; the buffer holds
     * max-frame pixels / 5 bytes (cam_hal.c), which a full-size frame fills at the floor. */
    uint64_t scaled = (uint64_t)CAM_QUALITY_FLOOR * FRAME_PIXELS[framesize];
    return (int32_t)(scaled / FRAME_PIXELS[limit]);
}

static int32_t field_max(cam_field_t field, uint8_t max_framesize)
{
    if (field == CAM_FIELD_FRAMESIZE) {
        return cam_cfg_framesize_limit(max_framesize);
    }
    return FIELD_INFO[field].max;
}

bool cam_cfg_validate(const cam_cfg_t *cfg, uint8_t max_framesize, cam_field_t *bad_field)
{
    for (int i = 0; i < (int)CAM_FIELD_COUNT; i++) {
        cam_field_t field = (cam_field_t)i;
        int32_t value = cam_cfg_get(cfg, field);
        if (value < FIELD_INFO[field].min || value > field_max(field, max_framesize)) {
            if (bad_field != NULL) {
                *bad_field = field;
            }
            return false;
        }
    }
    if (cfg->quality < cam_cfg_quality_min(cfg->framesize, max_framesize)) {
        if (bad_field != NULL) {
            *bad_field = CAM_FIELD_QUALITY;
        }
        return false;
    }
    return true;
}

cam_apply_result_t cam_cfg_apply_diff(const cam_cfg_t *current, const cam_cfg_t *wanted,
                                      cam_setter_t setter, void *ctx)
{
    cam_apply_result_t result = {0u, 0u, CAM_FIELD_COUNT};
    for (size_t i = 0; i < sizeof APPLY_ORDER / sizeof APPLY_ORDER[0]; i++) {
        cam_field_t field = APPLY_ORDER[i];
        int32_t value = cam_cfg_get(wanted, field);
        if (value == cam_cfg_get(current, field)) {
            continue;   /* SET_IF_DIFFERENT: untouched registers keep their state */
        }
        /* Keep going after a failure: the reply reports the sensor's real
         * state, so one unsupported setting must not block the others. */
        if (setter(ctx, field, value) == 0) {
            result.applied++;
        } else {
            if (result.failed == 0u) {
                result.first_failure = field;
            }
            result.failed++;
        }
    }
    return result;
}
