/* esp32-camera side of the camera node: initialisation and sensor settings. */
#ifndef CAMERA_HW_H
#define CAMERA_HW_H

#include <stdbool.h>
#include <stdint.h>

#include "camera_config.h"
#include "esp_err.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Starts the camera with buffers for max_framesize, then switches to QVGA. */
esp_err_t camera_hw_init(uint8_t max_framesize, int jpeg_quality);

/** Reads the sensor's current settings; false if the camera is not running. */
bool camera_hw_read(cam_cfg_t *out);

/** Applies the fields of wanted that differ from the sensor's current settings. */
cam_apply_result_t camera_hw_apply(const cam_cfg_t *wanted);

#ifdef __cplusplus
}
#endif

#endif /* CAMERA_HW_H */
