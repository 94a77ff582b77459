/* esp32-camera side of the camera node; see camera_hw.h. */
#include "camera_hw.h"

#include "esp_camera.h"
#include "esp_log.h"
#include "sdkconfig.h"

static const char *TAG = "camera_hw";

/* Kconfig's ESPDOCK_CAM_MAX_FRAMESIZE_VALUE, camera_config.h and CameraConfig.msg number frame
 * sizes as esp32-camera does from 2.0.14 on; older releases number them differently (VGA was
 * 8), which would silently select other sizes. */
_Static_assert(FRAMESIZE_QVGA == CAM_FRAMESIZE_QVGA, "esp32-camera >= 2.0.14 framesize_t numbering");
_Static_assert(FRAMESIZE_VGA == 10, "esp32-camera >= 2.0.14 framesize_t numbering");
_Static_assert(FRAMESIZE_UXGA == CAM_FRAMESIZE_UXGA, "esp32-camera >= 2.0.14 framesize_t numbering");

typedef struct {
    int pwdn, reset, xclk, siod, sioc;
    int d7, d6, d5, d4, d3, d2, d1, d0;
    int vsync, href, pclk;
} cam_pins_t;

/* Pin maps as in esp32-camera's own examples for these boards. An ESP32 board's map on another
 * chip names pins that do not exist there or are its flash/PSRAM pins. */
#if (CONFIG_ESPDOCK_CAM_BOARD_AI_THINKER || CONFIG_ESPDOCK_CAM_BOARD_WROVER_KIT) && !CONFIG_IDF_TARGET_ESP32
#error "the AI-Thinker and WROVER-KIT pin maps are for the ESP32 only"
#endif
#if CONFIG_ESPDOCK_CAM_BOARD_XIAO_ESP32S3 && !CONFIG_IDF_TARGET_ESP32S3
#error "the XIAO ESP32S3 Sense pin map is for the ESP32-S3 only"
#endif
#if CONFIG_ESPDOCK_CAM_BOARD_AI_THINKER
static const cam_pins_t PINS = {
    .pwdn = 32, .reset = -1, .xclk = 0, .siod = 26, .sioc = 27,
    .d7 = 35, .d6 = 34, .d5 = 39, .d4 = 36, .d3 = 21, .d2 = 19, .d1 = 18, .d0 = 5,
    .vsync = 25, .href = 23, .pclk = 22,
};
#elif CONFIG_ESPDOCK_CAM_BOARD_WROVER_KIT
static const cam_pins_t PINS = {
    .pwdn = -1, .reset = -1, .xclk = 21, .siod = 26, .sioc = 27,
    .d7 = 35, .d6 = 34, .d5 = 39, .d4 = 36, .d3 = 19, .d2 = 18, .d1 = 5, .d0 = 4,
    .vsync = 25, .href = 23, .pclk = 22,
};
#elif CONFIG_ESPDOCK_CAM_BOARD_XIAO_ESP32S3
/* esp32-camera's examples/camera_example/main/camera_pinout.h, BOARD_ESP32S3_XIAO. */
static const cam_pins_t PINS = {
    .pwdn = -1, .reset = -1, .xclk = 10, .siod = 40, .sioc = 39,
    .d7 = 48, .d6 = 11, .d5 = 12, .d4 = 14, .d3 = 16, .d2 = 18, .d1 = 17, .d0 = 15,
    .vsync = 38, .href = 47, .pclk = 13,
};
#else
static const cam_pins_t PINS = {
    .pwdn = CONFIG_ESPDOCK_CAM_PIN_PWDN, .reset = CONFIG_ESPDOCK_CAM_PIN_RESET,
    .xclk = CONFIG_ESPDOCK_CAM_PIN_XCLK, .siod = CONFIG_ESPDOCK_CAM_PIN_SIOD,
    .sioc = CONFIG_ESPDOCK_CAM_PIN_SIOC,
    .d7 = CONFIG_ESPDOCK_CAM_PIN_D7, .d6 = CONFIG_ESPDOCK_CAM_PIN_D6,
    .d5 = CONFIG_ESPDOCK_CAM_PIN_D5, .d4 = CONFIG_ESPDOCK_CAM_PIN_D4,
    .d3 = CONFIG_ESPDOCK_CAM_PIN_D3, .d2 = CONFIG_ESPDOCK_CAM_PIN_D2,
    .d1 = CONFIG_ESPDOCK_CAM_PIN_D1, .d0 = CONFIG_ESPDOCK_CAM_PIN_D0,
    .vsync = CONFIG_ESPDOCK_CAM_PIN_VSYNC, .href = CONFIG_ESPDOCK_CAM_PIN_HREF,
    .pclk = CONFIG_ESPDOCK_CAM_PIN_PCLK,
};
#endif

esp_err_t camera_hw_init(uint8_t max_framesize, int jpeg_quality)
{
    camera_config_t config = {
        .pin_pwdn = PINS.pwdn,
        .pin_reset = PINS.reset,
        .pin_xclk = PINS.xclk,
        .pin_sccb_sda = PINS.siod,
        .pin_sccb_scl = PINS.sioc,
        .pin_d7 = PINS.d7,
        .pin_d6 = PINS.d6,
        .pin_d5 = PINS.d5,
        .pin_d4 = PINS.d4,
        .pin_d3 = PINS.d3,
        .pin_d2 = PINS.d2,
        .pin_d1 = PINS.d1,
        .pin_d0 = PINS.d0,
        .pin_vsync = PINS.vsync,
        .pin_href = PINS.href,
        .pin_pclk = PINS.pclk,
        .xclk_freq_hz = CONFIG_ESPDOCK_CAM_XCLK_HZ,
        .ledc_timer = LEDC_TIMER_0,
        .ledc_channel = LEDC_CHANNEL_0,
        .pixel_format = PIXFORMAT_JPEG,
        /* The seed's trick: the JPEG buffers get width*height/5 bytes of the
         * size given here, so start at the largest size clients may pick and
         * every later set_framesize fits. */
        .frame_size = (framesize_t)max_framesize,
        .jpeg_quality = jpeg_quality,
        .fb_count = 2,
        .fb_location = CAMERA_FB_IN_PSRAM,
        /* Live stream: hand out the newest frame, not one queued while the
         * previous frame was being sent. */
        .grab_mode = CAMERA_GRAB_LATEST,
    };
    esp_err_t err = esp_camera_init(&config);
    if (err != ESP_OK) {
        ESP_LOGE(TAG, "esp_camera_init: %s", esp_err_to_name(err));
        return err;
    }
    sensor_t *sensor = esp_camera_sensor_get();
    if (sensor == NULL || sensor->set_framesize(sensor, FRAMESIZE_QVGA) != 0) {
        ESP_LOGE(TAG, "could not switch the sensor to QVGA");
        (void)esp_camera_deinit();
        return ESP_FAIL;
    }
    ESP_LOGI(TAG, "camera ready (PID 0x%x), buffers for framesize %u, streaming QVGA",
             (unsigned)sensor->id.PID, (unsigned)max_framesize);
    return ESP_OK;
}

bool camera_hw_read(cam_cfg_t *out)
{
    const sensor_t *sensor = esp_camera_sensor_get();
    if (sensor == NULL) {
        return false;
    }
    const camera_status_t *st = &sensor->status;
    out->framesize = (uint8_t)st->framesize;
    out->quality = st->quality;
    out->brightness = st->brightness;
    out->contrast = st->contrast;
    out->saturation = st->saturation;
    out->sharpness = st->sharpness;
    out->denoise = st->denoise;
    out->special_effect = st->special_effect;
    out->wb_mode = st->wb_mode;
    out->awb = st->awb;
    out->awb_gain = st->awb_gain;
    out->aec = st->aec;
    out->aec2 = st->aec2;
    out->ae_level = st->ae_level;
    out->aec_value = st->aec_value;
    out->agc = st->agc;
    out->agc_gain = st->agc_gain;
    out->gainceiling = st->gainceiling;
    out->bpc = st->bpc;
    out->wpc = st->wpc;
    out->raw_gma = st->raw_gma;
    out->lenc = st->lenc;
    out->hmirror = st->hmirror;
    out->vflip = st->vflip;
    out->dcw = st->dcw;
    out->colorbar = st->colorbar;
    out->pixformat = (uint8_t)sensor->pixformat;
    return true;
}

/* Maps a field to its sensor_t setter; each setter updates sensor->status. */
static int set_field(void *ctx, cam_field_t field, int32_t value)
{
    sensor_t *s = ctx;
    int (*setter)(sensor_t *, int) = NULL;
    switch (field) {
    case CAM_FIELD_FRAMESIZE:
        return s->set_framesize != NULL ? s->set_framesize(s, (framesize_t)value) : -1;
    case CAM_FIELD_GAINCEILING:
        return s->set_gainceiling != NULL ? s->set_gainceiling(s, (gainceiling_t)value) : -1;
    case CAM_FIELD_QUALITY: setter = s->set_quality; break;
    case CAM_FIELD_BRIGHTNESS: setter = s->set_brightness; break;
    case CAM_FIELD_CONTRAST: setter = s->set_contrast; break;
    case CAM_FIELD_SATURATION: setter = s->set_saturation; break;
    case CAM_FIELD_SHARPNESS: setter = s->set_sharpness; break;
    case CAM_FIELD_DENOISE: setter = s->set_denoise; break;
    case CAM_FIELD_SPECIAL_EFFECT: setter = s->set_special_effect; break;
    case CAM_FIELD_WB_MODE: setter = s->set_wb_mode; break;
    case CAM_FIELD_AWB: setter = s->set_whitebal; break;
    case CAM_FIELD_AWB_GAIN: setter = s->set_awb_gain; break;
    case CAM_FIELD_AEC: setter = s->set_exposure_ctrl; break;
    case CAM_FIELD_AEC2: setter = s->set_aec2; break;
    case CAM_FIELD_AE_LEVEL: setter = s->set_ae_level; break;
    case CAM_FIELD_AEC_VALUE: setter = s->set_aec_value; break;
    case CAM_FIELD_AGC: setter = s->set_gain_ctrl; break;
    case CAM_FIELD_AGC_GAIN: setter = s->set_agc_gain; break;
    case CAM_FIELD_BPC: setter = s->set_bpc; break;
    case CAM_FIELD_WPC: setter = s->set_wpc; break;
    case CAM_FIELD_RAW_GMA: setter = s->set_raw_gma; break;
    case CAM_FIELD_LENC: setter = s->set_lenc; break;
    case CAM_FIELD_HMIRROR: setter = s->set_hmirror; break;
    case CAM_FIELD_VFLIP: setter = s->set_vflip; break;
    case CAM_FIELD_DCW: setter = s->set_dcw; break;
    case CAM_FIELD_COLORBAR: setter = s->set_colorbar; break;
    default:
        return -1;  /* pixformat and unknown fields are never written */
    }
    /* Sensors leave setters they lack NULL or returning -1 (OV2640: sharpness, denoise). */
    return setter != NULL ? setter(s, (int)value) : -1;
}

cam_apply_result_t camera_hw_apply(const cam_cfg_t *wanted)
{
    cam_apply_result_t result = {0u, 0u, CAM_FIELD_COUNT};
    sensor_t *sensor = esp_camera_sensor_get();
    cam_cfg_t current;
    if (sensor == NULL || !camera_hw_read(&current)) {
        result.failed = 1u;
        return result;
    }
    result = cam_cfg_apply_diff(&current, wanted, set_field, sensor);
    if (result.failed > 0u) {
        const cam_field_info_t *info = cam_field_info(result.first_failure);
        ESP_LOGW(TAG, "%u setting(s) refused by the sensor, first: %s", result.failed,
                 info != NULL ? info->name : "?");
    }
    return result;
}
