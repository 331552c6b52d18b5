"""NMEA 0183 logs (pynmea2): RMC and GGA sentences with a fix, one per line.

An RMC sentence carries the date and time (UTC); a GGA sentence the time of day only: it takes the date of the
RMC sentences of the log, and a log of GGA sentences only counts its times from midnight of a day it does not
know (``dated`` False; the video's day is used, :mod:`.clock`). Other sentences, and lines that do not parse or
fail their checksum, are left out and counted in the log.
"""

from __future__ import annotations

import datetime

import numpy as np

from ...core.log import logger
from ...security.text import shown
from .base import Track, track_of

DAY = 86400.0
KINDS = ("RMC", "GGA")


def _fix(msg: object) -> tuple[float, float, float, datetime.date | None] | None:
    """``(seconds of the day, lat, lon, date or None)`` of an RMC / GGA sentence with a valid fix, else None."""
    kind = getattr(msg, "sentence_type", "")
    if kind == "RMC" and getattr(msg, "status", "") != "A":
        return None
    if kind == "GGA" and not str(getattr(msg, "gps_qual", "") or "0").strip("0"):
        return None
    t = msg.timestamp
    if not isinstance(t, datetime.time):
        return None
    day = t.hour * 3600 + t.minute * 60 + t.second + t.microsecond / 1e6
    date = getattr(msg, "datestamp", None) if kind == "RMC" else None
    return day, float(msg.latitude), float(msg.longitude), date if isinstance(date, datetime.date) else None


def _sentences(text: str, source: str) -> list[tuple[float, float, float, datetime.date | None]]:
    import pynmea2

    fixes, bad = [], 0
    for line in text.splitlines():
        line = line.strip()
        if not line.startswith(("$", "!")) or line[3:6] not in KINDS:
            continue
        try:
            fix = _fix(pynmea2.parse(line, check=True))
        except (pynmea2.ParseError, ValueError, TypeError, AttributeError, IndexError, OverflowError):
            bad += 1
            continue
        if fix is not None:
            fixes.append(fix)
    if bad:
        logger.warning("%s: %d RMC / GGA sentences do not parse (or fail their checksum); left out", shown(source), bad)
    return fixes


def parse_nmea(text: str, source: str) -> Track:
    """The fixes of the NMEA log ``text`` (read from ``source``): absolute UTC times when RMC sentences date them,
    else times of day (``dated`` False), a day added at each wrap past midnight."""
    fixes = _sentences(text, source)
    day = np.array([f[0] for f in fixes], np.float64)
    wraps = np.concatenate([[0], np.cumsum(np.diff(day) < -DAY / 2)]) if len(day) else day
    day = day + DAY * wraps  # a log running past midnight: its times go on
    dates = [(i, f[3]) for i, f in enumerate(fixes) if f[3] is not None]
    coords = [(f[1], f[2]) for f in fixes]
    if not dates:
        return track_of(day.tolist(), coords, source, dated=False)
    i, date = dates[0]  # the day of the first dated fix; every fix counted from it
    midnight = datetime.datetime.combine(date, datetime.time(), datetime.timezone.utc).timestamp()
    return track_of((midnight + day - DAY * wraps[i]).tolist(), coords, source)
