"""CameraConfig settings: ranges, labels, validation and form parsing, without rclpy.

The fields and their types come from the message itself (the node passes
`CameraConfig.get_fields_and_field_types()`; tests parse the .msg file), the
ranges from RANGES below, which must cover every field: a field added to the
message without a range here fails at start-up instead of going unvalidated.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

# Valid values per field, as in CameraConfig.msg's comments (the firmware's ranges).
RANGES: dict[str, tuple[int, int]] = {
    "framesize": (0, 15),
    "quality": (0, 63),
    "brightness": (-2, 2),
    "contrast": (-2, 2),
    "saturation": (-2, 2),
    "sharpness": (-2, 2),
    "denoise": (0, 255),
    "special_effect": (0, 6),
    "wb_mode": (0, 4),
    "awb": (0, 1),
    "awb_gain": (0, 1),
    "aec": (0, 1),
    "aec2": (0, 1),
    "ae_level": (-2, 2),
    "aec_value": (0, 1200),
    "agc": (0, 1),
    "agc_gain": (0, 30),
    "gainceiling": (0, 6),
    "bpc": (0, 1),
    "wpc": (0, 1),
    "raw_gma": (0, 1),
    "lenc": (0, 1),
    "hmirror": (0, 1),
    "vflip": (0, 1),
    "dcw": (0, 1),
    "colorbar": (0, 1),
    "pixformat": (0, 8),
}

# esp32-camera 2.x framesize_t: index -> (name, width, height).
FRAME_SIZES: tuple[tuple[str, int, int], ...] = (
    ("96X96", 96, 96),
    ("QQVGA", 160, 120),
    ("128X128", 128, 128),
    ("QCIF", 176, 144),
    ("HQVGA", 240, 176),
    ("240X240", 240, 240),
    ("QVGA", 320, 240),
    ("320X320", 320, 320),
    ("CIF", 400, 296),
    ("HVGA", 480, 320),
    ("VGA", 640, 480),
    ("SVGA", 800, 600),
    ("XGA", 1024, 768),
    ("HD", 1280, 720),
    ("SXGA", 1280, 1024),
    ("UXGA", 1600, 1200),
)
FRAMESIZE_QVGA = 6
PIXFORMAT_JPEG = 4

# Fields whose values name choices: shown as menus.
CHOICES: dict[str, tuple[str, ...]] = {
    "framesize": tuple(f"{name} ({w}x{h})" for name, w, h in FRAME_SIZES),
    "special_effect": ("none", "negative", "grayscale", "red tint", "green tint", "blue tint", "sepia"),
    "wb_mode": ("auto", "sunny", "cloudy", "office", "home"),
    "gainceiling": ("2x", "4x", "8x", "16x", "32x", "64x", "128x"),
    "pixformat": ("RGB565", "YUV422", "YUV420", "GRAYSCALE", "JPEG", "RGB888", "RAW", "RGB444", "RGB555"),
}

LABELS: dict[str, str] = {
    "framesize": "Frame size",
    "quality": "JPEG quality (lower is better)",
    "denoise": "Denoise",
    "special_effect": "Special effect",
    "wb_mode": "White balance mode",
    "awb": "Auto white balance",
    "awb_gain": "AWB gain",
    "aec": "Auto exposure",
    "aec2": "AEC DSP",
    "ae_level": "AE level",
    "aec_value": "Exposure (manual)",
    "agc": "Auto gain",
    "agc_gain": "Gain (manual)",
    "gainceiling": "Gain ceiling",
    "bpc": "Black pixel correction",
    "wpc": "White pixel correction",
    "raw_gma": "Raw gamma",
    "lenc": "Lens correction",
    "hmirror": "Horizontal mirror",
    "vflip": "Vertical flip",
    "dcw": "Downsize (DCW)",
    "colorbar": "Colour bar test pattern",
    "pixformat": "Pixel format",
}

# What the OV2640 reports after the firmware's init (seed 7.2.1: QVGA, quality 10).
DEFAULT_CONFIG: dict[str, int] = {
    "framesize": FRAMESIZE_QVGA,
    "quality": 10,
    "brightness": 0,
    "contrast": 0,
    "saturation": 0,
    "sharpness": 0,
    "denoise": 0,
    "special_effect": 0,
    "wb_mode": 0,
    "awb": 1,
    "awb_gain": 1,
    "aec": 1,
    "aec2": 0,
    "ae_level": 0,
    "aec_value": 168,
    "agc": 1,
    "agc_gain": 0,
    "gainceiling": 0,
    "bpc": 0,
    "wpc": 1,
    "raw_gma": 1,
    "lenc": 1,
    "hmirror": 0,
    "vflip": 0,
    "dcw": 1,
    "colorbar": 0,
    "pixformat": PIXFORMAT_JPEG,
}

# Bounds of the ROS integer types a field may have.
_TYPE_BOUNDS: dict[str, tuple[int, int]] = {
    "uint8": (0, 0xFF),
    "int8": (-0x80, 0x7F),
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFFFFFF),
    "int32": (-0x80000000, 0x7FFFFFFF),
}
# Generous: a form value longer than this is refused before int() sees it.
_INTEGER = re.compile(r"[+-]?[0-9]{1,7}")


class ConfigError(ValueError):
    """A configuration or form the camera would refuse; the message says which field and why."""


@dataclass(frozen=True)
class Setting:
    """One CameraConfig field as the UI shows it and the camera validates it."""

    name: str
    ros_type: str
    low: int
    high: int
    choices: tuple[str, ...] = ()
    read_only: bool = False

    @property
    def kind(self) -> str:
        """How the UI shows it: "menu", "toggle" or "slider"."""
        if self.choices:
            return "menu"
        if (self.low, self.high) == (0, 1):
            return "toggle"
        return "slider"

    @property
    def label(self) -> str:
        return LABELS.get(self.name, self.name.replace("_", " ").capitalize())

    def check(self, value: int) -> str | None:
        """Why VALUE is refused, or None when it is valid."""
        if isinstance(value, bool) or not isinstance(value, int):
            return f"{self.name} must be an integer, got {value!r}"
        if not self.low <= value <= self.high:
            return f"{self.name} must be in {self.low}..{self.high}, got {value}"
        return None


def settings_from_fields(fields: Mapping[str, str]) -> tuple[Setting, ...]:
    """The settings for a CameraConfig with FIELDS (name -> ROS type), in message order."""
    missing = [name for name in fields if name not in RANGES]
    if missing:
        raise ConfigError(f"CameraConfig fields without a range in camera_config.RANGES: {', '.join(missing)}")
    settings = []
    for name, ros_type in fields.items():
        bounds = _TYPE_BOUNDS.get(ros_type)
        if bounds is None:
            raise ConfigError(f"CameraConfig.{name} has type {ros_type}, not an integer type")
        low, high = RANGES[name]
        if not bounds[0] <= low <= high <= bounds[1]:
            raise ConfigError(f"range {low}..{high} of CameraConfig.{name} does not fit its type {ros_type}")
        # The camera node publishes JPEG whatever the sensor's format; the UI shows it, read-only.
        settings.append(Setting(name, ros_type, low, high, CHOICES.get(name, ()), read_only=name == "pixformat"))
    return tuple(settings)


def parse_msg_fields(text: str) -> dict[str, str]:
    """Field name -> type of a .msg file's text (constants and comments skipped)."""
    fields = {}
    for raw_line in text.splitlines():
        line = raw_line.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue
        ros_type, name = line.split()[:2]
        fields[name] = ros_type
    return fields


def validate(settings: Iterable[Setting], config: Mapping[str, int]) -> list[str]:
    """Every reason CONFIG would be refused; empty when the camera must accept it."""
    errors = []
    for setting in settings:
        if setting.name not in config:
            errors.append(f"{setting.name} is missing")
            continue
        problem = setting.check(config[setting.name])
        if problem:
            errors.append(problem)
    return errors


def parse_form(
    settings: Iterable[Setting], pairs: Iterable[tuple[str, str]], current: Mapping[str, int]
) -> dict[str, int]:
    """The config a submitted form asks for: CURRENT with the form's fields applied.

    PAIRS are the form's (name, value) pairs in order; a repeated name takes its
    last value (a toggle is a hidden "0" followed by a checkbox "1"). Raises
    ConfigError naming every bad field: unknown names, non-integers, out of range.
    """
    by_name = {s.name: s for s in settings}
    submitted: dict[str, str] = {}
    errors = []
    for name, value in pairs:
        if name not in by_name:
            errors.append(f"unknown setting {name[:40]!r}")
            continue
        submitted[name] = value
    config = {name: current.get(name, DEFAULT_CONFIG.get(name, by_name[name].low)) for name in by_name}
    for name, submitted_value in submitted.items():
        raw = submitted_value.strip()
        if raw == "on":  # a checkbox submitted without an explicit value
            raw = "1"
        if not _INTEGER.fullmatch(raw):
            errors.append(f"{name} must be an integer, got {raw[:40]!r}")
            continue
        value = int(raw)
        problem = by_name[name].check(value)
        if problem:
            errors.append(problem)
            continue
        config[name] = value
    if errors:
        raise ConfigError("; ".join(errors))
    return config


def frame_size(framesize: int) -> tuple[int, int]:
    """Width and height of framesize_t FRAMESIZE."""
    _, width, height = FRAME_SIZES[framesize]
    return width, height


def frame_size_name(framesize: int) -> str:
    """The esp32-camera name of FRAMESIZE, e.g. QVGA."""
    return FRAME_SIZES[framesize][0]
