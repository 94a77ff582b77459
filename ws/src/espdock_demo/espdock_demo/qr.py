"""QR decoding of camera frames and the detector's "publish only on change" rule, without rclpy."""

from __future__ import annotations

import ctypes
import enum
import functools
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
# (symbol type, data) pairs found in a picture; zbar's, through pyzbar, by default.
Decoder = Callable[[Image.Image], Sequence[Symbol]]


class ZbarQrDecoder:
    """QR codes zbar finds in an 8-bit grayscale picture: first on every second row and column,
    then, only where that found none, on every one.

    zbar spends nearly all of a frame's decoding scanning lines (1.3 ms of 1.4 ms for a QVGA
    frame here), and a QR code's finder patterns are 7 modules wide: a code whose modules are
    two pixels or more is found on half the lines in half the time. The full scan after an
    empty coarse one keeps smaller codes readable, at 1.5 times the cost for frames without
    a code. pyzbar's decode() offers no scan density, so this drives zbar through pyzbar's
    ctypes wrapper of zbar's API, with two scanners kept for the detector's life.
    """

    def __init__(self) -> None:
        from pyzbar import wrapper as zbar

        self._zbar = zbar
        self.coarse = self._scanner(2)
        self.full = self._scanner(1)

    def _scanner(self, density: int):
        zbar = self._zbar
        scanner = zbar.zbar_image_scanner_create()
        zbar.zbar_image_scanner_set_config(scanner, zbar.ZBarSymbol.NONE, zbar.ZBarConfig.CFG_ENABLE, 0)
        zbar.zbar_image_scanner_set_config(scanner, zbar.ZBarSymbol.QRCODE, zbar.ZBarConfig.CFG_ENABLE, 1)
        for axis in (zbar.ZBarConfig.CFG_X_DENSITY, zbar.ZBarConfig.CFG_Y_DENSITY):
            zbar.zbar_image_scanner_set_config(scanner, zbar.ZBarSymbol.NONE, axis, density)
        return scanner

    def __call__(self, image: Image.Image) -> list[Symbol]:
        if image.mode != "L":
            raise ValueError(f"zbar reads 8-bit grayscale pictures, not {image.mode}")
        return self.scan(self.coarse, image) or self.scan(self.full, image)

    def scan(self, scanner, image: Image.Image) -> list[Symbol]:
        """The QR codes SCANNER finds in IMAGE."""
        zbar = self._zbar
        pixels = image.tobytes()
        picture = zbar.zbar_image_create()
        try:
            zbar.zbar_image_set_format(picture, _GREY)
            zbar.zbar_image_set_size(picture, image.width, image.height)
            # zbar reads PIXELS during the scan only; the bytes object outlives it.
            zbar.zbar_image_set_data(picture, ctypes.cast(pixels, ctypes.c_void_p), len(pixels), None)
            if zbar.zbar_scan_image(scanner, picture) < 0:
                raise RuntimeError("zbar refused the picture")
            found = []
            symbol = zbar.zbar_image_first_symbol(picture)
            while symbol:
                data = ctypes.string_at(zbar.zbar_symbol_get_data(symbol), zbar.zbar_symbol_get_data_length(symbol))
                found.append((zbar.ZBarSymbol(symbol.contents.type).name, data))
                symbol = zbar.zbar_symbol_next(symbol)
            return found
        finally:
            zbar.zbar_image_destroy(picture)


# zbar's name for 8-bit grayscale, the fourcc "Y800" (pyzbar's decode uses the same).
_GREY = int.from_bytes(b"Y800", "little")


@functools.cache
def _shared_decoder() -> ZbarQrDecoder:
    return ZbarQrDecoder()


def pyzbar_decoder(image: Image.Image) -> list[Symbol]:
    """QR codes zbar finds in IMAGE (one ZbarQrDecoder, made on first use)."""
    return _shared_decoder()(image)


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
