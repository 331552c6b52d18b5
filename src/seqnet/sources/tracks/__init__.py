"""Positions by time: a GPS track (GPX, NMEA 0183, a CSV with a time column) read into one :class:`Track`.

:func:`read_track` reads any of :data:`TRACK_FORMATS` (recognised from the file's first characters: ``<`` GPX,
``$`` / ``!`` NMEA, else a CSV); :mod:`.clock` joins a track's times to a video's, :mod:`.metres` turns
latitude / longitude into metres (UTM) and :mod:`.interpolate` places each frame by its time.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ...core.errors import DatasetError
from ...security.inputs import read_text
from .base import MAX_TRACK_BYTES, Track, track_of
from .gpx import parse_gpx
from .nmea import parse_nmea
from .table import parse_csv

TRACK_FORMATS: dict[str, Callable[[str, str], Track]] = {"gpx": parse_gpx, "nmea": parse_nmea, "csv": parse_csv}
__all__ = ["MAX_TRACK_BYTES", "TRACK_FORMATS", "Track", "read_track", "track_of"]


def read_track(path: str | Path) -> Track:
    """The track in ``path``: GPX, NMEA 0183 (RMC / GGA) or CSV (:data:`TRACK_FORMATS`), by its first characters."""
    text = read_text(path, MAX_TRACK_BYTES, "positions file", DatasetError)
    head = text.lstrip("\ufeff \t\r\n")[:1]
    fmt = "gpx" if head == "<" else "nmea" if head in ("$", "!") else "csv"
    return TRACK_FORMATS[fmt](text, str(path))
