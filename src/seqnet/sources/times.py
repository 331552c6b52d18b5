"""One reading of absolute times for every source (video containers, GPX, NMEA, CSV tracks, ``--video-start``):
ISO-8601 text to an aware UTC datetime, and datetimes to seconds since the epoch. A time without a zone is UTC
(as GPX and NMEA times are, and as the video containers' ``creation_time`` is written)."""

from __future__ import annotations

import datetime


def as_utc(t: datetime.datetime) -> datetime.datetime:
    """``t`` with UTC as its zone when it has none (an aware ``t`` is returned as it is)."""
    return t if t.tzinfo else t.replace(tzinfo=datetime.timezone.utc)


def parse_iso(text: str) -> datetime.datetime:
    """An ISO-8601 time (``Z``, an offset or no zone: UTC) as an aware datetime; :class:`ValueError` if not one."""
    return as_utc(datetime.datetime.fromisoformat(text.strip().replace("Z", "+00:00")))


def utc_seconds(t: datetime.datetime) -> float:
    """Seconds since the epoch of ``t``; a time without a zone is UTC."""
    return as_utc(t).timestamp()
