"""Command-line values in the units people write: shutter speeds, sRGB hex colours, heights.

Each function is an argparse `type`: it returns the value in the project's units (seconds,
linear RGB in [0, 1], metres) or raises ArgumentTypeError with one line naming the value and,
where the value looks like another unit, the reading that was probably meant.
"""
from __future__ import annotations

import argparse
import math
import re
from fractions import Fraction

# Seconds per unit suffix of an exposure time ("us" and "µs" both microseconds), as exact
# fractions: the value is rounded to a float once, so "4ms" is the same double as "0.004".
_TIME_UNITS = {"": Fraction(1), "s": Fraction(1), "ms": Fraction(1, 1000), "us": Fraction(1, 10**6),
               "µs": Fraction(1, 10**6), "μs": Fraction(1, 10**6)}
_TIME_RE = re.compile(r"^\s*([0-9.eE+\-/ ]+?)\s*(s|ms|us|µs|μs)?\s*$")

# A camera held in a room: between a low tripod and a raised arm (metres).
HEIGHT_RANGE_M = (0.3, 3.0)
_FOOT_M = 0.3048


def seconds(s: str) -> float:
    """An exposure time as written on a camera or in EXIF: "1/250", "0.004", "4ms", "4 ms",
    "250us", "2s" or "1/250s"; returns seconds (finite, positive)."""
    m = _TIME_RE.match(s)
    if m is None:
        raise argparse.ArgumentTypeError(f"not an exposure time: {s!r} (write e.g. 1/250, 0.004 or 4ms)")
    try:
        v = float(Fraction(m.group(1).replace(" ", "")) * _TIME_UNITS[m.group(2) or ""])
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(f"not an exposure time: {s!r} (write e.g. 1/250, 0.004 or 4ms)") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"exposure time must be finite and positive, got {s!r}")
    return v


def srgb_to_linear(c: float) -> float:
    """The sRGB electro-optical transfer function (IEC 61966-2-1): encoded value in [0, 1] to
    linear reflectance in [0, 1]."""
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def srgb_hex(s: str) -> tuple[float, float, float]:
    """A colour written as sRGB hex, "#b4966a" (or "b4966a", or the short "#b96"), as linear
    RGB in [0, 1] (the object's diffuse albedo)."""
    h = s.strip().lstrip("#")
    if len(h) == 3:
        h = "".join(ch * 2 for ch in h)
    if not re.fullmatch(r"[0-9a-fA-F]{6}", h):
        raise argparse.ArgumentTypeError(f"expected an sRGB hex colour such as '#b4966a', got {s!r}")
    return tuple(srgb_to_linear(int(h[i:i + 2], 16) / 255.0) for i in (0, 2, 4))  # type: ignore[return-value]


def camera_height(s: str) -> float:
    """A camera's height above the floor in metres, within HEIGHT_RANGE_M; a value outside it is
    refused with the metres it would be in centimetres, millimetres or feet when one of those fits."""
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a height in metres, got {s!r}") from None
    lo, hi = HEIGHT_RANGE_M
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite height in metres, got {s!r}")
    if lo <= v <= hi:
        return v
    hint = ""
    for scale, unit in ((0.01, "centimetres"), (_FOOT_M, "feet"), (0.001, "millimetres")):
        if lo <= v * scale <= hi:
            hint = f"; did you mean {v * scale:.2f} m ({s} {unit})?"
            break
    raise argparse.ArgumentTypeError(
        f"{s} m is not a camera height: expected metres between {lo:g} and {hi:g}{hint}")
