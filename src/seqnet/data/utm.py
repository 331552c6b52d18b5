"""Latitude / longitude to UTM metres (``utm``), and the positions frame those metres are in (``UTM zone 32V``):
the one conversion of GPS logs, MSLS, bag NavSatFix topics and video tracks."""

from __future__ import annotations

import re

import numpy as np

from ..core.errors import DatasetError

UTM_FRAME = re.compile(r"UTM zone ([0-9]{1,2})([C-HJ-NP-X])")  # the positions frame of UTM metres: "UTM zone 32V"


def frame_zone(frame: str | None) -> tuple[int, str] | None:
    """``(number, band letter)`` of a positions frame ``UTM zone 32V``; None for another frame (or None)."""
    m = UTM_FRAME.fullmatch(frame or "")
    return None if m is None else (int(m.group(1)), m.group(2))


def latlon_to_utm(lat: np.ndarray, lon: np.ndarray, where: str,
                  zone: tuple[int, str] | None = None) -> tuple[np.ndarray, str]:
    """``[N, 2]`` UTM easting/northing of WGS84 ``lat, lon`` (degrees), all in ``zone`` (``(32, "U")``; default:
    the zone of the first point); and that zone (e.g. ``"32U"``). Out-of-range coordinates are refused with their
    index."""
    import utm

    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    bad = np.flatnonzero(~((lat >= -80) & (lat <= 84) & (np.abs(lon) <= 180)))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(f"{where}: sample {i}: latitude {float(lat[i])}, longitude {float(lon[i])} out of range "
                           "(UTM covers latitudes -80..84 and longitudes -180..180, degrees)")
    if zone is None:
        _, _, number, letter = utm.from_latlon(lat[:1], lon[:1])
        zone = (int(number), str(letter))
    try:
        e, n, _, _ = utm.from_latlon(lat, lon, force_zone_number=zone[0], force_zone_letter=zone[1])
    except ValueError as err:  # utm.error.OutOfRangeError: too far from the zone asked for
        raise DatasetError(f"{where}: cannot place its points in UTM zone {zone[0]}{zone[1]} ({err})") from err
    return np.stack([e, n], axis=1), f"{zone[0]}{zone[1]}"
