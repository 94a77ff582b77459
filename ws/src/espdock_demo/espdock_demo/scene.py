"""What camera_sim's camera sees: a desk with a QR code card, rendered with Pillow, as JPEG.

The sensor settings act on the picture as the OV2640's would, visibly: frame
size, JPEG quality, mirror and flip, brightness/contrast/saturation/sharpness,
special effects and the colour-bar test pattern. Codes are always full QR codes
(segno.make_qr): pyzbar cannot read the Micro QR codes segno.make picks for short texts.
"""

from __future__ import annotations

import io
from collections import OrderedDict
from collections.abc import Mapping

import segno
from PIL import Image, ImageDraw, ImageEnhance, ImageFont, ImageOps

from espdock_demo.camera_config import DEFAULT_CONFIG, frame_size
from espdock_demo.colors import parse_hex_color

_BACKGROUND = (196, 190, 178)
_COLORBARS = (
    (255, 255, 255),
    (255, 255, 0),
    (0, 255, 255),
    (0, 255, 0),
    (255, 0, 255),
    (255, 0, 0),
    (0, 0, 255),
    (0, 0, 0),
)
# special_effect: (dark, light) ends a grayscale picture is toned between.
_TONES = {3: ("#300000", "#ffb4b4"), 4: ("#003000", "#b4ffb4"), 5: ("#000030", "#b4b4ff"), 6: ("#2e1d0b", "#f1e3c6")}
# The settings that change the still picture (the rest only change the encoding).
_PICTURE_KEYS = (
    "framesize",
    "brightness",
    "contrast",
    "saturation",
    "sharpness",
    "special_effect",
    "hmirror",
    "vflip",
    "colorbar",
)


def jpeg_quality(esp_quality: int) -> int:
    """Pillow's JPEG quality (1..95, higher is better) for esp32-camera's 0..63 (lower is better)."""
    return max(5, min(95, round(95 - esp_quality * 90 / 63)))


def qr_image(payload: str | bytes, scale: int) -> Image.Image:
    """A full QR code for PAYLOAD with its quiet zone, SCALE pixels per module, black on white."""
    code = segno.make_qr(payload, error="m")
    rows = list(code.matrix_iter(scale=1, border=4))
    size = len(rows)
    small = Image.new("L", (size, size))
    small.putdata([0 if dark else 255 for row in rows for dark in row])
    return small.resize((size * scale, size * scale), Image.NEAREST)


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=max(8, size))
    except TypeError:  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def draw_scene(payload: str | bytes | None, width: int, height: int) -> Image.Image:
    """The desk with a card showing a QR code of PAYLOAD (None: an empty card), WIDTHxHEIGHT RGB."""
    image = Image.new("RGB", (width, height), _BACKGROUND)
    draw = ImageDraw.Draw(image)
    # A little depth so the picture is not flat: a darker band at the bottom (the desk's edge).
    draw.rectangle((0, height * 5 // 6, width, height), fill=(150, 140, 128))
    side = min(width, height)
    modules = segno.make_qr(payload, error="m").symbol_size(scale=1, border=4)[0] if payload is not None else 29
    scale = max(1, int(side * 0.62) // modules)
    card = side * 0.62 if payload is None else modules * scale
    left, top = (width - card) // 2, max(0, (height - card) // 2 - side // 14)
    if payload is None:
        draw.rectangle((left, top, left + card, top + card), fill=(255, 255, 255), outline=(120, 120, 120))
    else:
        image.paste(qr_image(payload, scale).convert("RGB"), (int(left), int(top)))
    caption = "no code" if payload is None else (payload if isinstance(payload, str) else payload.hex())[:24]
    rgb = parse_hex_color(caption)
    fill = (rgb.r, rgb.g, rgb.b) if rgb else (40, 40, 40)
    font = _font(max(8, height // 16))
    draw.text((width / 2, min(height - 2, top + card + height // 40)), caption, fill=fill, font=font, anchor="mt")
    return image


def draw_colorbars(width: int, height: int) -> Image.Image:
    """The sensor's colour-bar test pattern: eight vertical bars."""
    image = Image.new("RGB", (width, height))
    draw = ImageDraw.Draw(image)
    for i, color in enumerate(_COLORBARS):
        draw.rectangle((i * width // 8, 0, (i + 1) * width // 8, height), fill=color)
    return image


def apply_sensor(image: Image.Image, config: Mapping[str, int]) -> Image.Image:
    """IMAGE as the sensor settings in CONFIG change it (everything but size and quality)."""
    for key, enhancer, step in (
        ("brightness", ImageEnhance.Brightness, 0.3),
        ("contrast", ImageEnhance.Contrast, 0.3),
        ("saturation", ImageEnhance.Color, 0.5),
        ("sharpness", ImageEnhance.Sharpness, 0.8),
    ):
        level = config.get(key, 0)
        if level:
            image = enhancer(image).enhance(max(0.0, 1.0 + step * level))
    effect = config.get("special_effect", 0)
    if effect == 1:
        image = ImageOps.invert(image)
    elif effect == 2:
        image = image.convert("L").convert("RGB")
    elif effect in _TONES:
        dark, light = _TONES[effect]
        image = ImageOps.colorize(image.convert("L"), dark, light)
    if config.get("hmirror"):
        image = ImageOps.mirror(image)
    if config.get("vflip"):
        image = ImageOps.flip(image)
    return image


class SceneRenderer:
    """Renders frames of a scene for a config; the still picture is cached, each frame only adds a ticker."""

    def __init__(self, cache_size: int = 16) -> None:
        self._cache: OrderedDict[tuple, Image.Image] = OrderedDict()
        self._cache_size = cache_size

    def picture(self, payload: str | bytes | None, config: Mapping[str, int]) -> Image.Image:
        """The still picture (no ticker) of PAYLOAD's scene under CONFIG."""
        key = (payload, *(config.get(k, DEFAULT_CONFIG[k]) for k in _PICTURE_KEYS))
        cached = self._cache.get(key)
        if cached is not None:
            self._cache.move_to_end(key)
            return cached
        width, height = frame_size(config.get("framesize", DEFAULT_CONFIG["framesize"]))
        if config.get("colorbar"):
            picture = apply_sensor(draw_colorbars(width, height), {**config, "hmirror": 0, "vflip": 0})
        else:
            picture = apply_sensor(draw_scene(payload, width, height), config)
        self._cache[key] = picture
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return picture

    def frame(self, payload: str | bytes | None, config: Mapping[str, int], frame_number: int) -> bytes:
        """JPEG bytes of frame FRAME_NUMBER: the picture plus a moving ticker, so a live stream visibly moves."""
        image = self.picture(payload, config).copy()
        width, height = image.size
        draw = ImageDraw.Draw(image)
        bar = max(2, height // 60)
        x = (frame_number * max(1, width // 60)) % width
        draw.rectangle((0, height - bar, width, height), fill=(30, 30, 30))
        draw.rectangle((x, height - bar, min(width, x + width // 10), height), fill=(250, 250, 250))
        out = io.BytesIO()
        image.save(out, "JPEG", quality=jpeg_quality(config.get("quality", DEFAULT_CONFIG["quality"])))
        return out.getvalue()


def placeholder_jpeg(width: int, height: int, message: str) -> bytes:
    """A dark JPEG frame with MESSAGE in the middle (the UI's "no camera" frame)."""
    image = Image.new("RGB", (width, height), (24, 24, 28))
    draw = ImageDraw.Draw(image)
    draw.text((width / 2, height / 2), message, fill=(230, 80, 80), font=_font(height // 10), anchor="mm")
    out = io.BytesIO()
    image.save(out, "JPEG", quality=80)
    return out.getvalue()
