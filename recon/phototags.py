"""The EXIF tags photoar reads from a photo, through Pillow (PIL.Image.getexif):

- ExposureTime (Exif IFD, seconds), Orientation (IFD0, 1..8, the EXIF/TIFF convention; the pixels
  themselves are turned upright by recon.io.read_image_rgb, whose OpenCV decoder applies it);
- DateTimeOriginal ("YYYY:MM:DD HH:MM:SS", local clock time) and OffsetTimeOriginal ("+HH:MM",
  that clock's offset from UTC, EXIF 2.31) of the Exif IFD;
- GPSLatitude/GPSLatitudeRef, GPSLongitude/GPSLongitudeRef (degrees, minutes, seconds and N/S,
  E/W) and GPSAltitude/GPSAltitudeRef (metres, 1 = below sea level) of the GPS IFD.

Absent or unreadable tags are None: which ones a command needs, and the error naming the file and
the tag, is the caller's business (app/cmd_scene.py).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

TAG_ORIENTATION = 0x0112
TAG_EXPOSURE_TIME = 0x829A
TAG_DATETIME_ORIGINAL = 0x9003
TAG_OFFSET_TIME_ORIGINAL = 0x9011
IFD_EXIF = 0x8769
IFD_GPS = 0x8825
GPS_LAT_REF, GPS_LAT, GPS_LON_REF, GPS_LON, GPS_ALT_REF, GPS_ALT = 1, 2, 3, 4, 5, 6


@dataclass
class PhotoTags:
    exposure_time: float | None = None  # seconds
    orientation: int | None = None  # 1 = upright ... 8
    datetime_original: str | None = None  # "YYYY:MM:DD HH:MM:SS", the camera's local clock
    offset_time_original: str | None = None  # "+HH:MM": that clock's offset from UTC
    latitude: float | None = None  # degrees, north positive
    longitude: float | None = None  # degrees, east positive
    altitude_m: float | None = None  # metres above sea level


def _float(v) -> float | None:
    """A TIFF number (int, Pillow's IFDRational) as a finite float, else None."""
    try:
        x = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return x if x == x and abs(x) != float("inf") else None


def _text(v) -> str | None:
    if isinstance(v, bytes):
        v = v.decode("ascii", "replace")
    if not isinstance(v, str):
        return None
    v = v.strip("\x00 ")
    return v or None


def _dms(v, ref, positive: str, negative: str) -> float | None:
    """(degrees, minutes, seconds) with its N/S or E/W reference -> signed decimal degrees."""
    try:
        d, m, s = (_float(x) for x in v)
    except (TypeError, ValueError):
        return None
    ref = _text(ref)
    if d is None or m is None or s is None or ref is None or ref.upper() not in (positive, negative):
        return None
    x = d + m / 60.0 + s / 3600.0
    return -x if ref.upper() == negative else x


def read_tags(path: str | os.PathLike) -> PhotoTags:
    """The tags of an image file (an empty PhotoTags when it has no EXIF or Pillow cannot open it;
    recon.io.read_image_rgb reports unreadable images)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(Path(path)) as im:
            ex = im.getexif()
            sub = ex.get_ifd(IFD_EXIF)
            gps = ex.get_ifd(IFD_GPS)
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError):
        return PhotoTags()
    exp = _float(sub.get(TAG_EXPOSURE_TIME, ex.get(TAG_EXPOSURE_TIME)))
    ori = _float(ex.get(TAG_ORIENTATION))
    alt = _float(gps.get(GPS_ALT))
    ref = gps.get(GPS_ALT_REF)
    if alt is not None and (ref[:1] == b"\x01" if isinstance(ref, bytes) else _float(ref) == 1):
        alt = -alt
    return PhotoTags(
        exposure_time=exp if exp is not None and exp > 0 else None,
        orientation=int(ori) if ori is not None and 1 <= ori <= 8 else None,
        datetime_original=_text(sub.get(TAG_DATETIME_ORIGINAL)),
        offset_time_original=_text(sub.get(TAG_OFFSET_TIME_ORIGINAL)),
        latitude=_dms(gps.get(GPS_LAT), gps.get(GPS_LAT_REF), "N", "S"),
        longitude=_dms(gps.get(GPS_LON), gps.get(GPS_LON_REF), "E", "W"),
        altitude_m=alt)
