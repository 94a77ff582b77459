"""led_strip_sim: stands in for the LED strip firmware (seed 7.5) until a board is attached.

Same rule as the firmware, stricter than the seed: only `#RGB` and `#RRGGBB`
of hex digits change the colour; anything else is ignored and logged. The
colour the strip shows is published on change, transient-local, so a late
subscriber gets it at once.
"""

from __future__ import annotations

# First, before the slow imports: a stop while they run ends the node quietly.
import espdock_demo.stop_early  # noqa: F401

# isort: split

from rclpy.node import Node
from std_msgs.msg import ColorRGBA, String

from espdock_demo.colors import OFF, Rgb, parse_hex_color, shorten
from espdock_demo.names import LED_COLOR_TOPIC, QR_MESSAGE_TOPIC
from espdock_demo.ros_common import LATCHED_QOS, spin_node, start_diagnostics, start_heartbeat, subscribe_text


class LedStripSim(Node):
    """The simulated LED strip node."""

    def __init__(self) -> None:
        super().__init__("led_strip_sim")
        self.led_count = int(self.declare_parameter("led_count", 8).value)
        self.color = OFF
        self.changes = 0
        self.ignored = 0
        self.publisher = self.create_publisher(ColorRGBA, LED_COLOR_TOPIC, LATCHED_QOS)
        subscribe_text(self, QR_MESSAGE_TOPIC, self.on_message)
        start_heartbeat(self)
        start_diagnostics(self, self.diagnostics)
        self.show(OFF)
        self.get_logger().info(f"{self.led_count} LEDs off; taking colours from {QR_MESSAGE_TOPIC}")

    def show(self, color: Rgb) -> None:
        self.color = color
        r, g, b = color.as_floats()
        self.publisher.publish(ColorRGBA(r=r, g=g, b=b, a=1.0))

    def on_message(self, msg: String) -> None:
        color = parse_hex_color(msg.data)
        if color is None:
            self.ignored += 1
            self.get_logger().warning(f"ignored {shorten(msg.data)}: not a #RGB or #RRGGBB colour")
            return
        if color == self.color:
            return
        self.changes += 1
        self.show(color)
        # Debug, as qr_detector's line for a new code: the console says each colour.
        self.get_logger().debug(f"LED strip shows {color.hex}")

    def diagnostics(self) -> dict[str, object]:
        return {"color": self.color.hex, "changes": self.changes, "ignored": self.ignored}


def main() -> None:
    spin_node(LedStripSim)
