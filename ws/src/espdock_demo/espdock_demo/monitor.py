"""demo_monitor: the `demo` service's console: the UI's address, then QR codes and LED colours as they happen."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import ColorRGBA, String

from espdock_demo.colors import Rgb, shorten
from espdock_demo.names import DIAGNOSTICS_TOPIC, LED_COLOR_TOPIC, QR_MESSAGE_TOPIC
from espdock_demo.ros_common import LATCHED_QOS, TEXT_QOS, spin_node, start_heartbeat


class DemoMonitor(Node):
    """Logs the pipeline's events and, every `summary_period` seconds, the nodes' counters."""

    def __init__(self) -> None:
        super().__init__("demo_monitor")
        url = str(self.declare_parameter("ui_url", "http://127.0.0.1:8080").value)
        period = float(self.declare_parameter("summary_period", 15.0).value)
        self.latest: dict[str, dict[str, str]] = {}
        self.create_subscription(String, QR_MESSAGE_TOPIC, self.on_qr, TEXT_QOS)
        self.create_subscription(ColorRGBA, LED_COLOR_TOPIC, self.on_color, LATCHED_QOS)
        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self.on_diagnostics, 10)
        self.create_timer(period, self.summary)
        start_heartbeat(self)
        self.get_logger().info(f"espdock demo running: open {url} (Ctrl-C stops the demo)")

    def on_qr(self, msg: String) -> None:
        self.get_logger().info(f"QR code {shorten(msg.data)}")

    def on_color(self, msg: ColorRGBA) -> None:
        self.get_logger().info(f"LED strip shows {Rgb.from_floats(msg.r, msg.g, msg.b).hex}")

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.latest[status.name] = {kv.key: kv.value for kv in status.values}

    def summary(self) -> None:
        camera = self.latest.get("/camera_sim", {})
        detector = self.latest.get("/qr_detector", {})
        parts = []
        if camera:
            parts.append(f"camera_sim {camera.get('resolution')} {camera.get('frames_published')} frames")
        if detector:
            parts.append(f"qr_detector {detector.get('frames_decoded')} decoded "
                         f"({detector.get('decode_ms_avg')} ms each)")
        if parts:
            self.get_logger().info("; ".join(parts))


def main() -> None:
    spin_node(DemoMonitor)
