"""Fan-out of camera frames to many MJPEG clients without ever blocking the producer.

The ROS image callback calls FrameBroadcaster.publish, which only swaps the
latest-frame slot and wakes the waiting clients: it never waits for a client.
Each client thread takes the newest frame when it is ready for one, so a slow
browser skips frames instead of slowing the camera or the other browsers.
"""

from __future__ import annotations

import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

BOUNDARY = "espdockframe"
CONTENT_TYPE = f"multipart/x-mixed-replace; boundary={BOUNDARY}"


@dataclass(frozen=True)
class Frame:
    """One published frame: its sequence number, JPEG bytes and arrival time (monotonic seconds)."""

    seq: int
    data: bytes
    arrived: float


class FrameBroadcaster:
    """A latest-frame slot with a condition variable; see the module docstring."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._closed = False
        self._arrivals: deque[float] = deque(maxlen=256)

    def publish(self, data: bytes) -> None:
        """Make DATA the newest frame and wake every waiting client."""
        with self._cond:
            seq = self._frame.seq + 1 if self._frame else 1
            now = self._clock()
            self._frame = Frame(seq, data, now)
            self._arrivals.append(now)
            self._cond.notify_all()

    def latest(self) -> Frame | None:
        """The newest frame, if any arrived yet."""
        with self._cond:
            return self._frame

    def wait_newer(self, seq: int, timeout: float) -> Frame | None:
        """The newest frame after frame SEQ, waiting up to TIMEOUT seconds; None on timeout or close."""
        deadline = self._clock() + timeout
        with self._cond:
            while not self._closed and (self._frame is None or self._frame.seq <= seq):
                remaining = deadline - self._clock()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return None if self._closed else self._frame

    def age(self) -> float | None:
        """Seconds since the newest frame arrived, None when none ever did."""
        with self._cond:
            return None if self._frame is None else self._clock() - self._frame.arrived

    def rate(self, window: float = 2.0) -> float:
        """Frames per second over the last WINDOW seconds."""
        with self._cond:
            since = self._clock() - window
            return sum(1 for t in self._arrivals if t > since) / window

    def close(self) -> None:
        """Wake every client for good (server shutdown)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def multipart_chunk(jpeg: bytes) -> bytes:
    """JPEG as one part of a multipart/x-mixed-replace stream."""
    head = f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n".encode("ascii")
    return head + jpeg + b"\r\n"


# Start-of-frame markers that carry the picture size (baseline, extended, progressive, ...).
_SOF_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """Width and height from a JPEG's frame header without decoding it; None if it is not a JPEG."""
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _SOF_MARKERS:
            if i + 9 > len(data):
                return None
            height, width = struct.unpack(">HH", data[i + 5 : i + 9])
            return width, height
        i += 2 + length
    return None
