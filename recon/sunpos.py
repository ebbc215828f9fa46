"""The sun's direction in a room's axes from the date, time and place of the photo and a compass
bearing of the room.

Solar position: pvlib's NREL Solar Position Algorithm (pvlib.solarposition.spa_python; Reda &
Andreas 2004, +-0.0003 deg), chosen over lighter libraries because it is the reference the others
are measured against and installs from wheels; it costs ~1-2 s of import (pandas), paid only when
a sun is given by date and place. Inputs: the instant as an aware datetime (converted to UTC here),
latitude/longitude in degrees (north and east positive), the altitude in metres (the pressure for
refraction is the standard atmosphere's there, pvlib.atmosphere.alt2pres; 12 C). delta_t = TT - UT1
is pvlib's estimate for the year. Output: azimuth in degrees clockwise from true north and the
apparent (refraction-corrected) elevation above the horizon, i.e. where the light comes from.

Room axes (DESIGN.md: metres, +Y up, right-handed): `north_deg` is the compass bearing (degrees
clockwise from true north, seen from above) of the room's -z axis. Right-handedness with +Y up puts
+x at bearing north_deg + 90: standing in the room looking along -z, +x is on your right. A sun at
azimuth A and elevation h is then, with t = A - north_deg,

    direction_to_sun = (cos h sin t, sin h, -cos h cos t).

A wall's bearing is the bearing you face when you stand in the room looking at it (its outward
normal, the way a window in it looks out): back (the z-min wall) faces -z, front +z, left (x min)
-x, right (x max) +x, so north_deg = bearing(back) = bearing(front) - 180 = bearing(left) + 90 =
bearing(right) - 90.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np

# the bearing of a wall minus the bearing of -z (the wall names of recon.assemble.ROOM_FACE_NAMES)
WALL_OFFSET_DEG = {"back": 0.0, "front": 180.0, "left": -90.0, "right": 90.0}


@dataclass(frozen=True)
class SunPosition:
    azimuth_deg: float  # clockwise from true north, [0, 360)
    elevation_deg: float  # apparent elevation above the horizon (refraction included)


def solar_position(when: datetime, latitude: float, longitude: float, altitude_m: float = 0.0) -> SunPosition:
    """Azimuth and apparent elevation of the sun at `when` (an aware datetime) seen from latitude,
    longitude (degrees, north/east positive) and altitude_m (metres above sea level), by NREL SPA."""
    import pandas as pd
    from pvlib.atmosphere import alt2pres
    from pvlib.solarposition import spa_python

    if when.tzinfo is None or when.utcoffset() is None:
        raise ValueError(f"{when.isoformat()}: a time without a UTC offset")
    t = pd.DatetimeIndex([pd.Timestamp(when.astimezone(timezone.utc))])
    r = spa_python(t, float(latitude), float(longitude), altitude=float(altitude_m),
                   pressure=float(alt2pres(float(altitude_m))), delta_t=None)
    return SunPosition(float(r["azimuth"].iloc[0]) % 360.0, float(r["apparent_elevation"].iloc[0]))


def room_direction(azimuth_deg: float, elevation_deg: float, north_deg: float) -> np.ndarray:
    """(3,) unit vector towards a sun at (azimuth, elevation) in room axes whose -z axis has compass
    bearing north_deg (see the module docstring)."""
    t, h = math.radians(azimuth_deg - north_deg), math.radians(elevation_deg)
    return np.array([math.cos(h) * math.sin(t), math.sin(h), -math.cos(h) * math.cos(t)])


def north_from_wall(wall: str, bearing_deg: float) -> float:
    """The bearing of the room's -z axis from the bearing of a named wall (back, front, left, right),
    degrees in [0, 360)."""
    if wall not in WALL_OFFSET_DEG:
        raise ValueError(f"unknown wall {wall!r}: one of {', '.join(WALL_OFFSET_DEG)}")
    return (bearing_deg - WALL_OFFSET_DEG[wall]) % 360.0


_OFFSET = re.compile(r"^([+-])(\d{2}):?(\d{2})$")


def parse_offset(text: str) -> timezone:
    """A UTC offset "+02:00", "-0700" or "Z" -> timezone; ValueError otherwise."""
    if text.strip().upper() == "Z":
        return timezone.utc
    m = _OFFSET.match(text.strip())
    if not m or int(m.group(3)) >= 60 or int(m.group(2)) > 14:
        raise ValueError(f"not a UTC offset: {text!r} (expected e.g. +02:00)")
    sign = 1 if m.group(1) == "+" else -1
    return timezone(sign * timedelta(hours=int(m.group(2)), minutes=int(m.group(3))))


def parse_when(text: str) -> datetime:
    """An ISO 8601 date and time, e.g. 2026-06-21T15:30+02:00 or 2026-06-21 13:30Z; naive (no
    offset) when the text gives none: the caller decides whether that is allowed."""
    s = text.strip()
    if s[-1:] in "zZ":
        s = s[:-1] + "+00:00"
    try:
        return datetime.fromisoformat(s)
    except ValueError:
        raise ValueError(f"not a date and time: {text!r} (expected e.g. 2026-06-21T15:30+02:00)") from None


def parse_exif_time(datetime_original: str, offset_time_original: str | None) -> datetime:
    """EXIF DateTimeOriginal "YYYY:MM:DD HH:MM:SS" with OffsetTimeOriginal "+HH:MM" -> datetime
    (naive without an offset)."""
    try:
        t = datetime.strptime(datetime_original.strip(), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        raise ValueError(f"DateTimeOriginal {datetime_original!r} is not 'YYYY:MM:DD HH:MM:SS'") from None
    if offset_time_original is None:
        return t
    try:
        return t.replace(tzinfo=parse_offset(offset_time_original))
    except ValueError:
        raise ValueError(f"OffsetTimeOriginal {offset_time_original!r} is not a UTC offset like +02:00") from None


def parse_where(text: str) -> tuple[float, float, float | None]:
    """"LAT,LON" or "LAT,LON,ALT" (degrees north/east positive, metres) -> (lat, lon, alt or None)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) not in (2, 3) or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"expected LAT,LON or LAT,LON,ALT in degrees (north and east positive) and metres, "
                         f"got {text!r}")
    lat, lon = vals[0], vals[1]
    if not -90.0 <= lat <= 90.0:
        raise ValueError(f"latitude must be in [-90, 90] degrees, got {lat}")
    if not -180.0 <= lon <= 180.0:
        raise ValueError(f"longitude must be in [-180, 180] degrees, got {lon}")
    return lat, lon, (vals[2] if len(vals) == 3 else None)
