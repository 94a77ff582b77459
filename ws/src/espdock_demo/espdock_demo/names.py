"""Topic and service names shared with the firmware and other tools: keep them stable."""

CAMERA_IMAGE_TOPIC = "/esp32/camera/image_jpeg"
CAMERA_GET_CONFIG_SERVICE = "/esp32/camera/get_config"
CAMERA_SET_CONFIG_SERVICE = "/esp32/camera/set_config"
QR_MESSAGE_TOPIC = "/qr_message"
LED_COLOR_TOPIC = "/esp32/led_strip/color"
# Simulator-only ground truth: camera_sim announces each scene change here, stamped
# like the first frame that shows it, so benchmarks can time the pipeline.
SCENE_TOPIC = "/camera_sim/scene"
DIAGNOSTICS_TOPIC = "/diagnostics"

IMAGE_FORMAT = "jpeg"
CAMERA_FRAME_ID = "esp32_camera"

# Each node touches this file (ESPDOCK_HEARTBEAT overrides it) from its executor every
# second; its container's healthcheck and demo_watchdog read it.
HEARTBEAT_FILE_DEFAULT = "/tmp/espdock-heartbeat"
