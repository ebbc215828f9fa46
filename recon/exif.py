"""The two EXIF tags photoar needs from a phone's JPEG: ExposureTime (0x829A, seconds) and
Orientation (0x0112, 1..8), read from the APP1 "Exif" segment (TIFF layout, either byte order).

OpenCV decodes pixels but does not report EXIF, so this small reader parses the segment itself.
The pixels are turned upright by recon.io.read_image_rgb (OpenCV's decoder honours Orientation).
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path


TAG_ORIENTATION = 0x0112
TAG_EXIF_IFD = 0x8769
TAG_EXPOSURE_TIME = 0x829A
_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 9: 4, 10: 8}


@dataclass
class Exif:
    exposure_time: float | None = None  # seconds
    orientation: int | None = None  # 1 = upright ... 8 (EXIF/TIFF convention)


def _app1_exif(data: bytes) -> bytes | None:
    """The TIFF block of a JPEG's APP1 Exif segment, or None (not a JPEG, or no EXIF)."""
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker in (0xD9, 0xDA):  # end of image / start of scan: no more metadata
            return None
        if marker == 0xFF or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 1 if marker == 0xFF else 2
            continue
        (length,) = struct.unpack(">H", data[i + 2:i + 4])
        seg = data[i + 4:i + 2 + length]
        if marker == 0xE1 and seg[:6] == b"Exif\x00\x00":
            return seg[6:]
        i += 2 + length
    return None


def _ifd(tiff: bytes, offset: int, endian: str) -> dict[int, tuple[int, int, bytes]]:
    """tag -> (type, count, value bytes) of the IFD at `offset`."""
    out: dict[int, tuple[int, int, bytes]] = {}
    if offset + 2 > len(tiff):
        return out
    (n,) = struct.unpack(endian + "H", tiff[offset:offset + 2])
    for k in range(n):
        e = offset + 2 + 12 * k
        if e + 12 > len(tiff):
            break
        tag, typ, count = struct.unpack(endian + "HHI", tiff[e:e + 8])
        size = _TYPE_SIZE.get(typ, 1) * count
        if size <= 4:
            value = tiff[e + 8:e + 8 + size]
        else:
            (ptr,) = struct.unpack(endian + "I", tiff[e + 8:e + 12])
            value = tiff[ptr:ptr + size]
        out[tag] = (typ, count, value)
    return out


def _number(entry: tuple[int, int, bytes] | None, endian: str) -> float | None:
    if entry is None:
        return None
    typ, count, v = entry
    try:
        if typ == 3:
            return float(struct.unpack(endian + "H", v[:2])[0])
        if typ == 4:
            return float(struct.unpack(endian + "I", v[:4])[0])
        if typ in (5, 10):
            num, den = struct.unpack(endian + ("II" if typ == 5 else "ii"), v[:8])
            return num / den if den else None
    except struct.error:
        return None
    return None


def parse_exif(data: bytes) -> Exif:
    """ExposureTime and Orientation from a JPEG's bytes (fields None where absent or unreadable)."""
    tiff = _app1_exif(data)
    if tiff is None or len(tiff) < 8:
        return Exif()
    endian = {b"II": "<", b"MM": ">"}.get(tiff[:2])
    if endian is None:
        return Exif()
    (ifd0,) = struct.unpack(endian + "I", tiff[4:8])
    d0 = _ifd(tiff, ifd0, endian)
    exp = _number(d0.get(TAG_EXPOSURE_TIME), endian)
    ptr = _number(d0.get(TAG_EXIF_IFD), endian)
    if ptr is not None:
        exp = _number(_ifd(tiff, int(ptr), endian).get(TAG_EXPOSURE_TIME), endian) or exp
    ori = _number(d0.get(TAG_ORIENTATION), endian)
    return Exif(exp if exp is not None and exp > 0 else None,
                int(ori) if ori is not None and 1 <= ori <= 8 else None)


def read_exif(path: str | os.PathLike) -> Exif:
    """EXIF fields of an image file (empty Exif for non-JPEGs)."""
    with open(Path(path), "rb") as f:
        return parse_exif(f.read(1 << 20))  # EXIF lives in the first 64 KiB of a JPEG
