/*
 * Camera settings: range validation and "apply only what differs"
 * (hardware-free, host-tested).
 *
 * cam_cfg_t mirrors custom_interface/msg/CameraConfig field for field (same
 * names, same stdint types), so the app copies to and from the rosidl struct
 * with one macro and this file needs no micro-ROS or esp32-camera header.
 */
#ifndef CAMERA_CONFIG_H
#define CAMERA_CONFIG_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/*
 * One row per CameraConfig.msg field, in message order:
 *   X(name, ENUM_SUFFIX, c_type, min, max, writable)
 * Ranges are the message's (esp32-camera 2.x camera_status_t). pixformat is
 * reported but not writable: the node publishes CompressedImage "jpeg", and a
 * client that sends a zero-initialised pixformat must not break the stream.
 */
#define CAM_CFG_FIELDS(X)                                       \
    X(framesize,      FRAMESIZE,      uint8_t,  0,   15, true)  \
    X(quality,        QUALITY,        uint8_t,  0,   63, true)  \
    X(brightness,     BRIGHTNESS,     int8_t,  -2,    2, true)  \
    X(contrast,       CONTRAST,       int8_t,  -2,    2, true)  \
    X(saturation,     SATURATION,     int8_t,  -2,    2, true)  \
    X(sharpness,      SHARPNESS,      int8_t,  -2,    2, true)  \
    X(denoise,        DENOISE,        uint8_t,  0,  255, true)  \
    X(special_effect, SPECIAL_EFFECT, uint8_t,  0,    6, true)  \
    X(wb_mode,        WB_MODE,        uint8_t,  0,    4, true)  \
    X(awb,            AWB,            uint8_t,  0,    1, true)  \
    X(awb_gain,       AWB_GAIN,       uint8_t,  0,    1, true)  \
    X(aec,            AEC,            uint8_t,  0,    1, true)  \
    X(aec2,           AEC2,           uint8_t,  0,    1, true)  \
    X(ae_level,       AE_LEVEL,       int8_t,  -2,    2, true)  \
    X(aec_value,      AEC_VALUE,      uint16_t, 0, 1200, true)  \
    X(agc,            AGC,            uint8_t,  0,    1, true)  \
    X(agc_gain,       AGC_GAIN,       uint8_t,  0,   30, true)  \
    X(gainceiling,    GAINCEILING,    uint8_t,  0,    6, true)  \
    X(bpc,            BPC,            uint8_t,  0,    1, true)  \
    X(wpc,            WPC,            uint8_t,  0,    1, true)  \
    X(raw_gma,        RAW_GMA,        uint8_t,  0,    1, true)  \
    X(lenc,           LENC,           uint8_t,  0,    1, true)  \
    X(hmirror,        HMIRROR,        uint8_t,  0,    1, true)  \
    X(vflip,          VFLIP,          uint8_t,  0,    1, true)  \
    X(dcw,            DCW,            uint8_t,  0,    1, true)  \
    X(colorbar,       COLORBAR,       uint8_t,  0,    1, true)  \
    X(pixformat,      PIXFORMAT,      uint8_t,  0,    8, false)

#define CAM_CFG_DECLARE_FIELD(name, e, type, lo, hi, w) type name;
typedef struct {
    CAM_CFG_FIELDS(CAM_CFG_DECLARE_FIELD)
} cam_cfg_t;
#undef CAM_CFG_DECLARE_FIELD

#define CAM_CFG_DECLARE_ENUM(name, e, type, lo, hi, w) CAM_FIELD_##e,
typedef enum {
    CAM_CFG_FIELDS(CAM_CFG_DECLARE_ENUM)
    CAM_FIELD_COUNT
} cam_field_t;
#undef CAM_CFG_DECLARE_ENUM

/* framesize_t values used as limits (esp32-camera 2.x). */
#define CAM_FRAMESIZE_QVGA 6u
#define CAM_FRAMESIZE_UXGA 15u

/* The lowest JPEG quality value (the best quality, the largest frame) a frame filling the whole
 * buffer may use: esp32-camera's JPEG buffers hold width*height/5 bytes of the largest frame size,
 * and a frame that overflows them is dropped after a capture timeout of up to 4 s. */
#define CAM_QUALITY_FLOOR 10

/* The lowest quality value FRAMESIZE may use with buffers sized for MAX_FRAMESIZE: the floor
 * scaled by the frame's share of the buffer's pixels, rounded down (a frame of a quarter of the
 * pixels may go down to 2; QVGA in UXGA buffers to 0). */
int32_t cam_cfg_quality_min(uint8_t framesize, uint8_t max_framesize);

/* pixformat_t value of JPEG (esp32-camera 2.x), the only format the node publishes. */
#define CAM_PIXFORMAT_JPEG 4u

typedef struct {
    const char *name;
    int32_t min;
    int32_t max;
    bool writable;
} cam_field_info_t;

typedef struct {
    unsigned applied;           /* setter calls that succeeded */
    unsigned failed;            /* setter calls that failed (value left as the sensor has it) */
    cam_field_t first_failure;  /* CAM_FIELD_COUNT when nothing failed */
} cam_apply_result_t;

/* Applies one field to the hardware; returns 0 on success (esp32-camera convention). */
typedef int (*cam_setter_t)(void *ctx, cam_field_t field, int32_t value);

/** Name, message range and writability of a field; NULL for an invalid field. */
const cam_field_info_t *cam_field_info(cam_field_t field);

/** Value of one field, widened to int32_t. */
int32_t cam_cfg_get(const cam_cfg_t *cfg, cam_field_t field);

/** Stores value into one field, converted to the field's C type. */
void cam_cfg_set(cam_cfg_t *cfg, cam_field_t field, int32_t value);

/** Upper framesize limit the node accepts: the message's, lowered to max_framesize. */
int32_t cam_cfg_framesize_limit(uint8_t max_framesize);

/** True when every field is within range; otherwise *bad_field (if given) is the first offender. */
bool cam_cfg_validate(const cam_cfg_t *cfg, uint8_t max_framesize, cam_field_t *bad_field);

/** Calls setter for each writable field where wanted differs from current, mode switches before manual values. */
cam_apply_result_t cam_cfg_apply_diff(const cam_cfg_t *current, const cam_cfg_t *wanted,
                                      cam_setter_t setter, void *ctx);

#ifdef __cplusplus
}
#endif

#endif /* CAMERA_CONFIG_H */
