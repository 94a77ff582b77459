"""qr_detector (seed 7.4): decodes QR codes in the camera frames, publishes their text when it changes.

Subscribes with depth 1, best effort: a detector that falls behind gets the
newest frame, never a backlog. A bad frame (empty, corrupt, a code that is not
UTF-8) is logged and counted, never fatal.
"""

from __future__ import annotations

# First, before the slow imports: a stop while they run ends the node quietly.
import espdock_demo.stop_early  # noqa: F401

# isort: split

import time

from rclpy.node import Node
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import String

from espdock_demo.colors import shorten
from espdock_demo.names import CAMERA_IMAGE_TOPIC, QR_MESSAGE_TOPIC
from espdock_demo.qr import ChangeFilter, Outcome, decode_frame
from espdock_demo.ros_common import IMAGE_SUB_QOS, LATCHED_QOS, spin_node, start_diagnostics, start_heartbeat


class QrDetector(Node):
    """The QR detector node."""

    def __init__(self) -> None:
        super().__init__("qr_detector")
        self.filter = ChangeFilter()
        self.frames_received = 0
        self.decode_seconds = 0.0
        # Latched: a node that starts (or restarts) later gets the text in view now (subscribe_text).
        self.publisher = self.create_publisher(String, QR_MESSAGE_TOPIC, LATCHED_QOS)
        self.create_subscription(CompressedImage, CAMERA_IMAGE_TOPIC, self.on_image, IMAGE_SUB_QOS)
        start_heartbeat(self)
        start_diagnostics(self, self.diagnostics)
        self.get_logger().info(f"decoding QR codes from {CAMERA_IMAGE_TOPIC}, publishing changes on {QR_MESSAGE_TOPIC}")

    def on_image(self, msg: CompressedImage) -> None:
        self.frames_received += 1
        begin = time.perf_counter()
        result = decode_frame(bytes(msg.data))
        self.decode_seconds += time.perf_counter() - begin
        text = self.filter.feed(result)
        log = self.get_logger()
        if result.outcome is Outcome.CORRUPT:
            log.warning(
                f"ignored a frame that is not an image ({len(msg.data)} bytes): {result.detail}",
                throttle_duration_sec=2.0,
            )
        elif result.outcome is Outcome.EMPTY:
            log.warning("ignored an empty frame", throttle_duration_sec=2.0)
        elif result.outcome is Outcome.NOT_UTF8:
            log.warning(f"ignored a QR code whose bytes are not UTF-8: {result.raw!r}", throttle_duration_sec=2.0)
        elif result.outcome is Outcome.NO_CODE:
            log.debug("no QR code in frame", throttle_duration_sec=5.0)
        if text is not None:
            self.publisher.publish(String(data=text))
            # Debug, not info: an info line (console, /rosout, log file) took a core while the LED
            # strip and the readers took the text: with this line and the LED strip's off, LED ->
            # observer's reader went from 0.9-1.2 to 0.45 ms p50 on two cores.
            # The console, demo_monitor, says each new code.
            log.debug(f"new QR code {shorten(text)}")

    def diagnostics(self) -> dict[str, object]:
        counts = self.filter.counts
        return {
            "frames_received": self.frames_received,
            "frames_decoded": sum(counts.values()),
            **{f"frames_{k}": v for k, v in counts.items()},
            "decode_ms_avg": round(1000 * self.decode_seconds / max(1, self.frames_received), 3),
            "decode_seconds": round(self.decode_seconds, 4),
            "cpu_seconds": round(time.process_time(), 3),
            "last_text": (self.filter.last or "")[:64],
        }


def main() -> None:
    spin_node(QrDetector)
