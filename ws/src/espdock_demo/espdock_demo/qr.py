"""QR decoding of camera frames and the detector's "publish only on change" rule, without rclpy."""

from __future__ import annotations

import enum
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from PIL import Image, UnidentifiedImageError

# Pillow refuses to decode more pixels than this (a decompression bomb guard);
# the largest real frame is UXGA, 1600x1200.
_MAX_PIXELS = 4096 * 4096


class Outcome(enum.StrEnum):
    """What one frame gave."""

    CODE = "code"  # a QR code with UTF-8 text
    NO_CODE = "no_code"  # a good picture without a readable code
    EMPTY = "empty"  # no bytes at all
    CORRUPT = "corrupt"  # bytes that are not a decodable image
    NOT_UTF8 = "not_utf8"  # a code whose bytes are not UTF-8 text


@dataclass(frozen=True)
class FrameResult:
    """The outcome of one frame and, for CODE, the decoded text (for NOT_UTF8, the raw bytes)."""

    outcome: Outcome
    text: str = ""
    raw: bytes = b""
    detail: str = ""


Symbol = tuple[str, bytes]
# (symbol type, data) pairs found in a picture; pyzbar's decode by default.
Decoder = Callable[[Image.Image], Sequence[Symbol]]


def pyzbar_decoder(image: Image.Image) -> list[Symbol]:
    """QR codes pyzbar finds in IMAGE."""
    from pyzbar.pyzbar import ZBarSymbol, decode

    return [(result.type, result.data) for result in decode(image, symbols=[ZBarSymbol.QRCODE])]


def decode_frame(jpeg: bytes, decoder: Decoder = pyzbar_decoder) -> FrameResult:
    """The QR text in the JPEG frame JPEG; never raises for bad input, it says what was wrong."""
    if not jpeg:
        return FrameResult(Outcome.EMPTY, detail="empty image data")
    try:
        image = Image.open(io.BytesIO(jpeg))
        if image.width * image.height > _MAX_PIXELS:
            return FrameResult(Outcome.CORRUPT, detail=f"{image.width}x{image.height} is larger than any camera frame")
        # zbar reads 8-bit grayscale: a JPEG is decoded straight to it (its luma plane
        # only, no chroma upsampling or colour conversion); anything else is converted.
        image.draft("L", image.size)
        image.load()
        if image.mode != "L":
            image = image.convert("L")
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        return FrameResult(Outcome.CORRUPT, detail=f"{type(exc).__name__}: {exc}"[:200])
    symbols = decoder(image)
    if not symbols:
        return FrameResult(Outcome.NO_CODE)
    _, data = symbols[0]
    try:
        return FrameResult(Outcome.CODE, text=data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        return FrameResult(Outcome.NOT_UTF8, raw=data[:64], detail=str(exc))


@dataclass
class ChangeFilter:
    """Passes on a QR text only when it differs from the last one passed (seed 7.4.2)."""

    last: str | None = None
    counts: dict[str, int] = field(default_factory=lambda: {o.value: 0 for o in Outcome})

    def feed(self, result: FrameResult) -> str | None:
        """Count RESULT; the text to publish, or None when there is nothing new."""
        self.counts[result.outcome.value] += 1
        if result.outcome is not Outcome.CODE or result.text == self.last:
            return None
        self.last = result.text
        return result.text
