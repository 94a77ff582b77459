"""demo_monitor: the `demo` service's console: the nodes as they come up, the UI's address once it is up,
then QR codes and LED colours as they happen."""

from __future__ import annotations

# First, before the slow imports: a stop while they run ends the node quietly.
import espdock_demo.stop_early  # noqa: F401

# isort: split

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import ColorRGBA, String

from espdock_demo.colors import Rgb, shorten
from espdock_demo.health import SIM_NODES, NodeHealth
from espdock_demo.names import DIAGNOSTICS_TOPIC, LED_COLOR_TOPIC, QR_MESSAGE_TOPIC
from espdock_demo.ros_common import LATCHED_QOS, TEXT_QOS, positive_setting, spin_node, start_heartbeat
from espdock_demo.web import address_to_open


class DemoMonitor(Node):
    """Logs the pipeline's events and, every `summary_period` seconds, the nodes' counters."""

    def __init__(self) -> None:
        super().__init__("demo_monitor")
        self.url = address_to_open(str(self.declare_parameter("ui_url", "http://127.0.0.1:8080").value))
        period = positive_setting(self, "summary_period", 15.0, "seconds between summary lines")
        watched = list(self.declare_parameter("watch_nodes", list(SIM_NODES)).value)
        self.latest: dict[str, dict[str, str]] = {}
        self.health = NodeHealth(watched)
        self.states = self.health.report()
        self.create_subscription(String, QR_MESSAGE_TOPIC, self.on_qr, TEXT_QOS)
        self.create_subscription(ColorRGBA, LED_COLOR_TOPIC, self.on_color, LATCHED_QOS)
        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self.on_diagnostics, 10)
        self.create_timer(period, self.summary)
        self.create_timer(1.0, self.watch)
        self.ui_announced = False
        start_heartbeat(self)
        # Compose starts this console beside the nodes, not after them: the address comes once
        # the UI node reports (it serves before it spins, so it reports only when it serves).
        self.get_logger().info(f"espdock demo starting: waiting for {', '.join(n.lstrip('/') for n in watched)}")

    def on_qr(self, msg: String) -> None:
        self.get_logger().info(f"QR code {shorten(msg.data)}")

    def on_color(self, msg: ColorRGBA) -> None:
        self.get_logger().info(f"LED strip shows {Rgb.from_floats(msg.r, msg.g, msg.b).hex}")

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.latest[status.name] = {kv.key: kv.value for kv in status.values}
            self.health.seen(status.name)

    def watch(self) -> None:
        """Say at once when a node goes silent and when it is back."""
        states = self.health.report()
        logger = self.get_logger()
        for line in self.health.changes(self.states, states):
            # One call site per severity: rclpy refuses a call site whose severity changes
            # ("Logger severity cannot be changed between calls"), which killed the monitor.
            if "down" in line:
                logger.warning(line)
            else:
                logger.info(line)
        self.states = states
        if not self.ui_announced and states.get("/camera_ui", {}).get("state") == "ok":
            self.ui_announced = True
            # Ctrl-C stops every service only as `make demo` runs it (`up --attach demo`); under
            # `docker compose up demo` it stops this console alone, and "stops the demo" left it running.
            logger.info(
                f"espdock demo running: open {self.url} (`make demo`: Ctrl-C stops it; "
                "else `docker compose --profile '*' down`)"
            )

    def summary(self) -> None:
        # A silent node's last counters would read as if all were well.
        fresh = {name for name, state in self.states.items() if state["state"] == "ok"}
        camera = self.latest.get("/camera_sim", {}) if "/camera_sim" in fresh else {}
        detector = self.latest.get("/qr_detector", {}) if "/qr_detector" in fresh else {}
        down = sorted(name.lstrip("/") for name, state in self.states.items() if state["state"] in ("stale", "missing"))
        parts = [f"DOWN: {', '.join(down)}"] if down else []
        if camera:
            parts.append(f"camera_sim {camera.get('resolution')} {camera.get('frames_published')} frames")
        if detector:
            parts.append(
                f"qr_detector {detector.get('frames_decoded')} decoded ({detector.get('decode_ms_avg')} ms each)"
            )
        if parts:
            self.get_logger().info("; ".join(parts))


# The console reads what came every 0.1 s, not on each message: woken by each QR text and
# LED colour, its Python and its log lines ran beside the detector and the LED strip at the
# moments they work. With the console frozen (docker pause), LED -> observer's reader went from
# 0.24-0.44 to 0.18 ms p50 on two cores. People read it later than 0.1 s anyway.
POLL_SECONDS = 0.1


def main() -> None:
    spin_node(DemoMonitor, poll_period=POLL_SECONDS)
