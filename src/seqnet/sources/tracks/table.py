"""CSV tracks: a header with a time column and either latitude / longitude (degrees) or x / y (metres).

Fields are separated by ``,``, ``;`` or a tab (as the header is: :func:`seqnet.data.readers.field_separator`, as
positions CSVs), and a UTF-8 byte-order mark (Excel's "CSV UTF-8") is dropped.

* time (``time``, ``t``, ``timestamp``, ``seconds``): numbers are seconds since the video's start, but for Unix
  epoch times (seconds around 1.7e9, or milliseconds, microseconds, nanoseconds: :func:`.base.epoch_unit`),
  which are absolute, as ISO-8601 times (``2024-05-01T10:00:00.5Z``; one without a zone is UTC) are: they join
  the video by its clock.
* ``lat`` / ``latitude`` and ``lon`` / ``lng`` / ``long`` / ``longitude``; or ``easting`` / ``northing``, ``x`` / ``y``
  (metres, in the track's own frame).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import io

import numpy as np

from ...core.errors import DatasetError
from ...data.readers import field_separator
from ...security.text import shown
from ..times import utc_seconds
from .base import Track, epoch_unit, track_of

TIME_COLUMNS = ("time", "t", "timestamp", "seconds")
COORDINATES = ((("lat", "latitude"), ("lon", "lng", "long", "longitude")), (("easting", "x"), ("northing", "y")))


def _column(header: list[str], names: tuple[str, ...]) -> int | None:
    return next((header.index(n) for n in names if n in header), None)


def _time(text: str, where: str) -> tuple[float, bool, bool]:
    """``(seconds, absolute, zoned)`` of a time cell: a number (seconds since the video's start) or ISO-8601
    (``zoned``: it names its zone; one without is read as UTC)."""
    text = text.strip()
    try:
        return float(text), False, True
    except ValueError:
        pass
    try:
        t = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))  # parsed once: its zone, then UTC seconds
        return utc_seconds(t), True, t.tzinfo is not None
    except (ValueError, OverflowError, OSError) as e:
        raise DatasetError(f"{where}: time {shown(text)[:60]} is neither seconds nor an ISO-8601 time") from e


def _rows(text: str, source: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    text = text.removeprefix("\ufeff")
    first = next((line for line in text.splitlines() if line.strip()), "")
    try:
        reader = csv.reader(io.StringIO(text, newline=""), delimiter=field_separator(first) or ",")
        rows = [(n, r) for n, r in enumerate(reader, start=1) if r and any(c.strip() for c in r)]
    except csv.Error as e:
        raise DatasetError(f"{shown(source)}: not a valid CSV file ({' '.join(str(e).split())[:200]})") from e
    if len(rows) < 2:
        raise DatasetError(f"{shown(source)}: a CSV track needs a header row and at least one data row")
    return [h.strip().lower() for h in rows[0][1]], rows[1:]


def parse_csv(text: str, source: str) -> Track:
    """The track of a CSV ``text`` (read from ``source``); a row it cannot read is an error naming its line."""
    header, rows = _rows(text, source)
    tcol = _column(header, TIME_COLUMNS)
    found = [(_column(header, a), _column(header, b)) for a, b in COORDINATES]
    geographic = None not in found[0]
    cols = found[0] if geographic else found[1]
    if tcol is None or None in cols:
        raise DatasetError(f"{shown(source)}: a CSV track needs a time column ({', '.join(TIME_COLUMNS)}) and "
                           f"lat, lon (degrees) or x, y / easting, northing (metres); its header: "
                           f"{shown(','.join(header))[:200]}")
    times, coords, kinds, zoned = [], [], set(), True
    for line, r in rows:
        where = f"{shown(source)}, line {line}"
        if len(r) <= max(tcol, *cols):
            raise DatasetError(f"{where}: {len(r)} fields, but the header has {len(header)}")
        t, absolute, has_zone = _time(r[tcol], where)
        kinds.add(absolute)
        zoned = zoned and has_zone
        try:
            coords.append((float(r[cols[0]]), float(r[cols[1]])))
        except ValueError as e:
            comma = " (decimal commas? write 63.43, not 63,43)" if "," in r[cols[0]] + r[cols[1]] else ""
            raise DatasetError(f"{where}: position {shown(r[cols[0]])[:40]}, {shown(r[cols[1]])[:40]} is not two "
                               f"numbers{comma}") from e
        times.append(t)
    if len(kinds) > 1:
        raise DatasetError(f"{shown(source)}: some times are seconds and some ISO-8601 times; one kind per track")
    absolute = kinds.pop()
    unit = None if absolute else epoch_unit(np.asarray(times, np.float64))
    if unit is not None:
        track = track_of([t / unit[0] for t in times], coords, source, absolute=True, geographic=geographic)
        return dataclasses.replace(track, epoch=unit[1])
    track = track_of(times, coords, source, absolute=absolute, geographic=geographic)
    return track if zoned else dataclasses.replace(track, zoned=False)
