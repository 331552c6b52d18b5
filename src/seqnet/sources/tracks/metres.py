"""A track's coordinates in metres: latitude / longitude to UTM easting / northing (``utm``), in a zone given
(the reference's, or a map's) or the zone of the track's first point; x / y tracks are metres already."""

from __future__ import annotations

import re

import numpy as np

from ...core.errors import DatasetError
from ...security.text import shown
from .base import Track

UTM_FRAME = re.compile(r"UTM zone ([0-9]{1,2})([C-HJ-NP-X])")
XY_FRAME = "x, y metres of the positions files"


def utm_zone(frame: str | None) -> tuple[int, str] | None:
    """``(number, letter)`` of a frame ``UTM zone 32V``; None for another frame (or None)."""
    m = UTM_FRAME.fullmatch(frame or "")
    return None if m is None else (int(m.group(1)), m.group(2))


def to_metres(track: Track, zone: tuple[int, str] | None = None) -> tuple[np.ndarray, str]:
    """``(xy [S, 2] metres, frame)`` of the track: UTM in ``zone`` (default: its first point's), frame ``UTM zone
    32V``; or its own x, y (frame :data:`XY_FRAME`)."""
    if not track.geographic:
        return track.coords, XY_FRAME
    import utm

    lat, lon = track.coords[:, 0], track.coords[:, 1]
    if np.any((lat < -80) | (lat > 84)):
        raise DatasetError(f"{shown(track.source)}: a latitude outside -80..84 degrees, which UTM does not cover")
    if zone is None:
        _, _, number, letter = utm.from_latlon(lat[:1], lon[:1])
        zone = (int(number), str(letter))
    try:
        e, n, _, _ = utm.from_latlon(lat, lon, force_zone_number=zone[0], force_zone_letter=zone[1])
    except ValueError as err:  # utm.error.OutOfRangeError
        raise DatasetError(f"{shown(track.source)}: cannot place its points in UTM zone {zone[0]}{zone[1]} "
                           f"({err})") from err
    return np.stack([e, n], axis=1), f"UTM zone {zone[0]}{zone[1]}"
