"""Hex colour codes as the LED strip accepts them: `#RGB` or `#RRGGBB`, hex digits only."""

from __future__ import annotations

import re
from dataclasses import dataclass

# The firmware's rule, made strict: the seed's parser (7.5.2) turned any 4- or
# 7-character string starting with '#' into some colour; here anything that is
# not exactly hex digits of those lengths is refused.
_HEX_COLOR = re.compile(r"#([0-9A-Fa-f]{3}|[0-9A-Fa-f]{6})")


@dataclass(frozen=True)
class Rgb:
    """An LED colour, 0..255 per channel."""

    r: int
    g: int
    b: int

    @property
    def hex(self) -> str:
        return f"#{self.r:02x}{self.g:02x}{self.b:02x}"

    def as_floats(self) -> tuple[float, float, float]:
        """The colour as 0..1 floats (std_msgs/ColorRGBA)."""
        return (self.r / 255.0, self.g / 255.0, self.b / 255.0)

    @classmethod
    def from_floats(cls, r: float, g: float, b: float) -> Rgb:
        """The nearest 0..255 colour to 0..1 floats, clamped."""
        return cls(*(max(0, min(255, round(v * 255.0))) for v in (r, g, b)))


OFF = Rgb(0, 0, 0)


def parse_hex_color(text: str) -> Rgb | None:
    """The colour TEXT names (`#1af` is `#11aaff`), or None when it is not a colour code."""
    match = _HEX_COLOR.fullmatch(text)
    if match is None:
        return None
    digits = match.group(1)
    if len(digits) == 3:
        digits = "".join(d * 2 for d in digits)
    return Rgb(int(digits[0:2], 16), int(digits[2:4], 16), int(digits[4:6], 16))


def shorten(text: str, limit: int = 60) -> str:
    """TEXT for a log line: repr-quoted, cut to LIMIT characters with its full length noted."""
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}... ({len(text)} characters)"
