"""camera_sim: stands in for the ESP32-CAM firmware (seed 7.2) until a board is attached.

Publishes JPEG frames of a scene whose QR code cycles through `colors` (then a
phase with no code when `blank_phase`), `phase_duration` seconds each, at `fps`.
Serves get/set config like the firmware: a request with any field out of range
is refused whole (status false, config unchanged); accepted settings change the
frames. Each scene change is announced on /camera_sim/scene, stamped like the
first frame that shows it, for benchmarks.
"""

from __future__ import annotations

# First, before the slow imports: a stop while they run ends the node quietly.
import espdock_demo.stop_early  # noqa: F401

# isort: split

import json
import time

from custom_interface.msg import CameraConfig
from custom_interface.srv import GetCameraConfig, SetCameraConfig
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import String

from espdock_demo import camera_config
from espdock_demo.colors import shorten
from espdock_demo.names import (
    CAMERA_FRAME_ID,
    CAMERA_GET_CONFIG_SERVICE,
    CAMERA_IMAGE_TOPIC,
    CAMERA_SET_CONFIG_SERVICE,
    IMAGE_FORMAT,
    SCENE_TOPIC,
)
from espdock_demo.ros_common import (
    IMAGE_PUB_QOS,
    LATCHED_QOS,
    SettingError,
    config_to_dict,
    positive_setting,
    spin_node,
    start_diagnostics,
    start_heartbeat,
)
from espdock_demo.scene import SceneRenderer

DEFAULT_COLORS = ["#ff0000", "#00ff00", "#0000ff", "#ffff00", "#ff00ff", "#00ffff"]


class CameraSim(Node):
    """The simulated ESP32 camera node."""

    def __init__(self) -> None:
        super().__init__("camera_sim")
        # dynamic_typing: `-p fps:=30` (an integer) is as good as 30.0.
        self.fps = positive_setting(self, "fps", 30.0, "frames per second")
        # `colors:=[]` has no element type to give: rclpy's value is None, no list.
        colors = list(
            self.declare_parameter(
                "colors", DEFAULT_COLORS, ParameterDescriptor(description="QR texts the scene cycles through")
            ).value
            or ()
        )
        self.phase_duration = positive_setting(
            self, "phase_duration", 3.0, "seconds each QR text (and the blank phase) stays in view"
        )
        blank = bool(
            self.declare_parameter(
                "blank_phase", True, ParameterDescriptor(description="end each cycle with a phase showing no code")
            ).value
        )
        framesize = int(self.declare_parameter("framesize", camera_config.FRAMESIZE_QVGA).value)
        quality = int(self.declare_parameter("quality", camera_config.DEFAULT_CONFIG["quality"]).value)

        self.settings = camera_config.settings_from_fields(CameraConfig.get_fields_and_field_types())
        self.config = dict(camera_config.DEFAULT_CONFIG, framesize=framesize, quality=quality)
        errors = camera_config.validate(self.settings, self.config)
        if errors:
            raise SettingError("bad initial camera settings: " + "; ".join(errors))
        self.phases: list[str | None] = [str(c) for c in colors] + ([None] if blank or not colors else [])
        self.renderer = SceneRenderer()
        self.started = time.monotonic()
        self.frames_published = 0
        self.scene_changes = 0
        self.render_seconds = 0.0
        self.current: str | bool | None = False  # False: nothing shown yet

        self.image_pub = self.create_publisher(CompressedImage, CAMERA_IMAGE_TOPIC, IMAGE_PUB_QOS)
        self.scene_pub = self.create_publisher(String, SCENE_TOPIC, LATCHED_QOS)
        self.create_service(GetCameraConfig, CAMERA_GET_CONFIG_SERVICE, self.on_get_config)
        self.create_service(SetCameraConfig, CAMERA_SET_CONFIG_SERVICE, self.on_set_config)
        self.create_timer(1.0 / self.fps, self.on_frame)
        start_heartbeat(self)
        start_diagnostics(self, self.diagnostics)
        width, height = camera_config.frame_size(self.config["framesize"])
        self.get_logger().info(
            f"publishing {width}x{height} JPEG frames at {self.fps:g} fps on {CAMERA_IMAGE_TOPIC}; "
            f"scene cycles {', '.join(p or '(no code)' for p in self.phases)} every {self.phase_duration:g} s"
        )

    def phase(self) -> str | None:
        index = int((time.monotonic() - self.started) / self.phase_duration) % len(self.phases)
        return self.phases[index]

    def on_frame(self) -> None:
        text = self.phase()
        begin = time.perf_counter()
        jpeg = self.renderer.frame(text, self.config, self.frames_published)
        self.render_seconds += time.perf_counter() - begin
        msg = CompressedImage(format=IMAGE_FORMAT)
        msg.header.frame_id = CAMERA_FRAME_ID
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.data = jpeg
        self.image_pub.publish(msg)
        self.frames_published += 1
        if text != self.current:
            self.current = text
            self.scene_changes += 1
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            self.scene_pub.publish(
                String(data=json.dumps({"text": text, "stamp_ns": stamp_ns, "frame": self.frames_published}))
            )

    def on_get_config(self, request: GetCameraConfig.Request, response: GetCameraConfig.Response):
        response.config = CameraConfig(**self.config)
        return response

    def on_set_config(self, request: SetCameraConfig.Request, response: SetCameraConfig.Response):
        wanted = config_to_dict(request.config)
        errors = camera_config.validate(self.settings, wanted)
        if errors:
            self.get_logger().warning("refused settings: " + "; ".join(errors))
            response.status = False
        else:
            changed = {k: v for k, v in wanted.items() if self.config.get(k) != v}
            self.config = wanted
            response.status = True
            if changed:
                self.get_logger().info("applied " + shorten(", ".join(f"{k}={v}" for k, v in changed.items()), 200))
        response.config = CameraConfig(**self.config)
        return response

    def diagnostics(self) -> dict[str, object]:
        width, height = camera_config.frame_size(self.config["framesize"])
        return {
            "frames_published": self.frames_published,
            "scene_changes": self.scene_changes,
            "render_ms_avg": round(1000 * self.render_seconds / max(1, self.frames_published), 3),
            "resolution": f"{width}x{height}",
            "scene": self.current if isinstance(self.current, str) else "",
            "cpu_seconds": round(time.process_time(), 3),
        }


def main() -> None:
    spin_node(CameraSim)
