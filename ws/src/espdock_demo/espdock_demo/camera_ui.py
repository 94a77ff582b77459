"""camera_ui (seed 7.3): the web page with the live camera, its settings, the QR text and the LED colour.

ROS callbacks only hand data to the web side (a latest-frame slot, a state
object) and return; HTTP threads do the sending. Settings go to the camera's
set_config service and the page shows the configuration the camera answers
with, or an error when it does not answer within `service_timeout` seconds.
"""

from __future__ import annotations

# First, before the slow imports: a stop while they run ends the node quietly.
import espdock_demo.stop_early  # noqa: F401

# isort: split

import threading
import time

from custom_interface.msg import CameraConfig
from custom_interface.srv import GetCameraConfig, SetCameraConfig
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import ColorRGBA

from espdock_demo import camera_config
from espdock_demo.colors import Rgb
from espdock_demo.health import SIM_NODES, NodeHealth
from espdock_demo.mjpeg import FrameBroadcaster
from espdock_demo.names import (
    CAMERA_GET_CONFIG_SERVICE,
    CAMERA_IMAGE_TOPIC,
    CAMERA_SET_CONFIG_SERVICE,
    DIAGNOSTICS_TOPIC,
    LED_COLOR_TOPIC,
    QR_MESSAGE_TOPIC,
)
from espdock_demo.ros_common import (
    IMAGE_SUB_QOS,
    LATCHED_QOS,
    SettingError,
    config_to_dict,
    positive_setting,
    spin_node,
    start_diagnostics,
    start_heartbeat,
    subscribe_text,
)
from espdock_demo.web import CameraUnavailable, LiveState, SetResult, UiApp, make_server


class CameraUi(Node):
    """The camera UI node; also the web server's Backend."""

    def __init__(self) -> None:
        super().__init__("camera_ui")
        host = str(self.declare_parameter("host", "127.0.0.1").value)
        port = int(self.declare_parameter("port", 8080).value)
        if not 0 <= port <= 65535:
            raise SettingError(f"port:={port}: the UI's TCP port must be 0..65535")
        service_timeout = positive_setting(self, "service_timeout", 3.0, "seconds a camera service call may take")
        offline_after = positive_setting(self, "offline_after", 2.0, "seconds without a frame before offline")
        self.config_every = positive_setting(self, "config_every", 2.0, "seconds between asks for the camera's config")

        self.frames = FrameBroadcaster()
        self.state = LiveState()
        settings = camera_config.settings_from_fields(CameraConfig.get_fields_and_field_types())
        self.app = UiApp(settings, self.frames, self.state, self, service_timeout, offline_after)
        self.get_client = self.create_client(GetCameraConfig, CAMERA_GET_CONFIG_SERVICE)
        self.set_client = self.create_client(SetCameraConfig, CAMERA_SET_CONFIG_SERVICE)
        self.set_lock = threading.Lock()
        self.get_pending = None
        self.config_asked = float("-inf")
        # Bumped as each set_config begins and ends: a get_config answer that overlapped one may hold
        # the config it replaced.
        self.sets = 0

        self.create_subscription(CompressedImage, CAMERA_IMAGE_TOPIC, self.on_image, IMAGE_SUB_QOS)
        subscribe_text(self, QR_MESSAGE_TOPIC, lambda m: self.state.update(qr=m.data))
        self.create_subscription(ColorRGBA, LED_COLOR_TOPIC, self.on_color, LATCHED_QOS)
        self.create_timer(0.5, self.watch_camera)
        watched = list(self.declare_parameter("watch_nodes", list(SIM_NODES)).value)
        self.health = NodeHealth([n for n in watched if n != "/camera_ui"])
        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self.on_diagnostics, 10)
        self.create_timer(1.0, lambda: self.state.update(nodes=self.health.report()))
        self.beat_age = start_heartbeat(self)
        start_diagnostics(
            self, lambda: {"camera_online": self.app.camera_online(), "fps_in": round(self.frames.rate(), 1)}
        )

        self.server = make_server(host, port, self.app)
        threading.Thread(
            target=self.server.serve_forever, kwargs={"poll_interval": 0.5}, name="http", daemon=True
        ).start()
        self.get_logger().info(f"camera UI at http://{host}:{port}/")

    # ROS side: hand over and return at once.

    def on_image(self, msg: CompressedImage) -> None:
        self.frames.publish(bytes(msg.data))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != self.get_fully_qualified_name():
                self.health.seen(status.name)

    def on_color(self, msg: ColorRGBA) -> None:
        self.state.update(led=Rgb.from_floats(msg.r, msg.g, msg.b))

    def watch_camera(self) -> None:
        """Ask for the camera's config at start and every `config_every` seconds while it streams. Others
        change it too (a `ros2 service call`, a camera restarted with its defaults): the page showed the
        config of its last ask, and its Apply, which sends the whole form, put back what they had set."""
        online = self.app.camera_online()
        due = time.monotonic() - self.config_asked >= self.config_every
        unknown = self.state.get("config") is None
        if (unknown or (online and due)) and self.get_pending is None and self.get_client.service_is_ready():
            self.config_asked = time.monotonic()
            sets = self.sets
            self.get_pending = self.get_client.call_async(GetCameraConfig.Request())
            self.get_pending.add_done_callback(lambda future: self.on_config(future, sets))

    def on_config(self, future, sets: int) -> None:
        self.get_pending = None
        if future.cancelled() or future.exception() is not None or sets != self.sets:
            return
        self.state.update(config=config_to_dict(future.result().config))

    # Web side (HTTP threads).

    def set_config(self, config, timeout: float) -> SetResult:
        with self.set_lock:
            if not self.set_client.service_is_ready():
                raise CameraUnavailable(
                    f"The camera's {CAMERA_SET_CONFIG_SERVICE} service is not available: is the camera running?", 503
                )
            self.sets += 1
            done = threading.Event()
            future = self.set_client.call_async(SetCameraConfig.Request(config=CameraConfig(**config)))
            future.add_done_callback(lambda _: done.set())
            if not done.wait(timeout):
                self.set_client.remove_pending_request(future)
                future.cancel()
                raise CameraUnavailable(
                    f"The camera did not answer within {timeout:g} s; nothing is known to have changed.", 504
                )
            response = future.result()
            self.sets += 1
            return SetResult(bool(response.status), config_to_dict(response.config))

    def healthy(self) -> bool:
        return self.beat_age() < 5.0

    def stop(self) -> None:
        self.app.stopping.set()
        self.frames.close()
        self.server.shutdown()
        self.server.server_close()


def main() -> None:
    spin_node(CameraUi, on_shutdown=lambda node: node.stop())
