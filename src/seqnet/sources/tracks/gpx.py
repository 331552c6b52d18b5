"""GPX tracks (gpxpy): the points of every track segment (and route or waypoint when there is no track) that carry
a time, in UTC.

A document declaring a DTD (``<!DOCTYPE``, where entities are declared) is refused before it is parsed.
"""

from __future__ import annotations

from ...core.errors import DatasetError
from ...security.text import shown
from ..times import utc_seconds
from .base import Track, track_of

PARSE_ERRORS = (ValueError, TypeError, AttributeError, IndexError, KeyError, OverflowError, RecursionError)


def parse_gpx(text: str, source: str) -> Track:
    """The timed points of the GPX document ``text`` (read from ``source``) as an absolute geographic track."""
    import gpxpy
    import gpxpy.gpx

    if "<!DOCTYPE" in text.upper() or "<!ENTITY" in text.upper():
        raise DatasetError(f"{shown(source)}: the GPX file declares a DTD or entities; seqnet reads GPX without them")
    try:
        doc = gpxpy.parse(text)
        points = [p for trk in doc.tracks for seg in trk.segments for p in seg.points]
        points = points or [p for r in doc.routes for p in r.points] or list(doc.waypoints)
        timed = [(utc_seconds(p.time), (float(p.latitude), float(p.longitude))) for p in points if p.time is not None]
    except (gpxpy.gpx.GPXException, *PARSE_ERRORS) as e:
        raise DatasetError(f"{shown(source)}: not a GPX file seqnet can read ({type(e).__name__}: "
                           f"{shown(' '.join(str(e).split()))[:200]})") from e
    if not timed:
        raise DatasetError(f"{shown(source)}: none of its {len(points)} GPX points has a time (<time>), so none can be "
                           "placed on the video's clock")
    return track_of([t for t, _ in timed], [c for _, c in timed], source)
