"""A track's coordinates in metres: latitude / longitude to UTM easting / northing
(:func:`seqnet.data.utm.latlon_to_utm`), in a zone given (the reference's, or a map's) or the zone of the track's
first point; x / y tracks are metres already."""

from __future__ import annotations

import numpy as np

from ...data.utm import latlon_to_utm
from ...security.text import shown
from .base import Track

XY_FRAME = "x, y metres of the positions files"


def to_metres(track: Track, zone: tuple[int, str] | None = None) -> tuple[np.ndarray, str]:
    """``(xy [S, 2] metres, frame)`` of the track: UTM in ``zone`` (default: its first point's), frame ``UTM zone
    32V``; or its own x, y (frame :data:`XY_FRAME`)."""
    if not track.geographic:
        return track.coords, XY_FRAME
    xy, found = latlon_to_utm(track.coords[:, 0], track.coords[:, 1], shown(track.source), zone)
    return xy, f"UTM zone {found}"
