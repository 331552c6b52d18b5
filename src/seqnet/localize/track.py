"""A video query's sampling and GPS track, settled before any frame is localised.

* :func:`resolve_sampling`: the query video is sampled as the map's was (``dataset from-video --fps F`` or
  ``--every-metres M``, recorded in the map as ``sampling``) unless the user says otherwise, and a rate other than
  the map's is warned: SeqMatch-style matchers compare the two sequences frame by frame.
* :func:`place_track`: the ``--positions`` track joined to a video file's clock before decoding it, refused when it
  places no frame (:func:`seqnet.sources.tracks.clock.why_outside`: times in milliseconds, a gap, no overlap) or
  places none near the map's
  route (lat and lon swapped, another place): such a run has nothing to score. Frames off the track are localised
  without ground truth (``outside``); with ``--every-metres`` they are kept by time, at the rate kept along it.
* after the run, a near-constant time offset between where the frames were estimated and where the track puts
  them (a video clock a few seconds off) is found by :func:`seqnet.sources.tracks.offset.clock_offset`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import logger
from ..security.text import shown

if TYPE_CHECKING:
    from ..sources.placed import JoinedTrack


@dataclasses.dataclass(frozen=True)
class Sampling:
    """How a video is sampled: ``fps`` frames kept per second, or one per ``every_metres`` travelled (None, None:
    every frame); ``source``: ``map`` (as the map was), ``options`` (the user's) or ``every frame``."""

    fps: float | None = None
    every_metres: float | None = None
    source: str = "every frame"

    def said(self) -> str:
        """``5 frames/s``, ``one frame per 20 m`` or ``every frame``."""
        if self.every_metres is not None:
            return f"one frame per {self.every_metres:g} m"
        return "every frame" if self.fps is None else f"{self.fps:g} frames/s"


def map_sampling(meta: Mapping[str, Any]) -> Sampling | None:
    """The sampling recorded in a dataset's metadata or an index map's ``source`` (``dataset from-video``); None
    when the map was not made from a video (nothing recorded, or not numbers)."""
    s = meta.get("sampling")
    if not isinstance(s, Mapping):
        return None
    fps, metres = s.get("fps"), s.get("every_metres")
    ok = all(v is None or (isinstance(v, int | float) and not isinstance(v, bool) and v > 0) for v in (fps, metres))
    return Sampling(None if metres else fps, metres, "map") if ok else None


def resolve_sampling(fps: float | None, every_metres: float | None, recorded: Sampling | None,
                     positions: bool) -> Sampling:
    """The sampling of the query video: the user's ``--fps`` / ``--every-metres`` when given (warned when the map
    recorded another), else the map's ``recorded`` one (by distance only with a track: ``positions``)."""
    if fps is not None and every_metres is not None:
        raise ConfigError("give one of --fps and --every-metres (frames kept per second, or one per metres travelled)")
    if every_metres is not None and not positions:
        raise ConfigError("--every-metres needs the query's track (--positions FILE): distances come from it")
    if fps is not None or every_metres is not None:
        chosen = Sampling(fps, every_metres, "options")
        if recorded is not None and (recorded.fps, recorded.every_metres) != (fps, every_metres):
            logger.warning("the map keeps %s of its video, this query %s: SeqMatch-style matchers compare the two "
                           "sequences frame by frame, so sample both alike (hint: %s)", recorded.said(),
                           chosen.said(), _flag(recorded) or "drop --fps / --every-metres")
        return chosen
    if recorded is None or (recorded.fps is None and recorded.every_metres is None):
        return Sampling()
    if recorded.every_metres is not None and not positions:
        logger.warning("the map keeps %s of its video; without the query's track (--positions FILE) it cannot be "
                       "sampled by distance and is localised at every frame (hint: --positions FILE, or --fps F "
                       "giving about %g m between frames)", recorded.said(), recorded.every_metres)
        return Sampling()
    return recorded


def _flag(s: Sampling) -> str:
    return f"--every-metres {s.every_metres:g}" if s.every_metres is not None else \
        "" if s.fps is None else f"--fps {s.fps:g}"


def place_track(video: str | Path, positions: str | Path, start: Any, zone: tuple[int, str] | None,
                r_pos: np.ndarray, radius: float, every_metres: float | None,
                on_frame: Callable[[str], None] | None = None,
                max_gap: float | None = None, stream: int = 0) -> tuple[JoinedTrack, np.ndarray | None]:
    """The track ``positions`` on the video file ``video`` (recorded from ``start``, a datetime or None), in the
    UTM ``zone`` of the map whose reference positions are ``r_pos [R, 2]``: refused (:class:`DatasetError`) when it
    places no frame, or none within ``radius`` of the map's route; a track that leaves frames out is warned (how
    many, where, what happens to them). With the track, the video times of the frames ``every_metres`` keeps
    (None without it; the frames off the track by time, :func:`with_untracked`).
    ``on_frame`` checks the frame of the track's positions (e.g. the map's UTM zone) before they are compared;
    ``stream``: the video stream read (the number :func:`seqnet.sources.video.choose_stream` chose)."""
    from ..sources.placed import join_track
    from ..sources.sampling import every_metres as by_metres
    from ..sources.tracks.clock import check_placed, why_outside
    from ..sources.tracks.interpolate import DEFAULT_MAX_GAP
    from ..sources.video import VideoFile

    gap = DEFAULT_MAX_GAP if max_gap is None else max_gap
    v = VideoFile(video, stream)
    track = join_track(positions, start, v.duration, zone)
    if on_frame is not None:
        on_frame(track.frame)
    xy, inside = track.at(v.times, gap)
    where = f"the track {shown(positions)[:120]}"
    placed, n = int(inside.sum()), len(v.times)
    said = f"{where} places {placed or 'none'} of the {n} frames of {shown(video)[:120]}"
    line = check_placed(placed, n, track.times, v.duration, gap, said, v.times, inside)
    check_near_route(xy[inside], r_pos, radius, where, track.geographic)
    kept = None
    if every_metres is not None:
        kept = v.times[inside][by_metres(xy[inside], every_metres)]
        if placed < n:  # no metres off the track: the frames there are kept at the rate kept along it
            kept, rate = with_untracked(kept, v.times[~inside])
            line = line or f"{said}: {why_outside(track.times, v.duration, gap, v.times, inside)}"
            line = (f"{line}; with no track to measure metres on, those frames are sampled by time at {rate} "
                    f"(the rate one frame per {every_metres:g} m kept along the track), localised, and left out of "
                    "the scores (outside)")
    elif line:
        line += "; they are localised, and left out of the scores (outside)"
    if line:
        logger.warning("%s", line)
    return track, kept


def with_untracked(kept: np.ndarray, untracked: np.ndarray) -> tuple[np.ndarray, str]:
    """``(times [K'], rate said)``: the sorted video times ``kept [K]`` that per-metre sampling kept along a
    track, with the times ``untracked [U]`` of the frames off the track (no metres there) kept by time at the
    mean rate of ``kept`` (every frame when that has no rate: under two frames, or no time between them)."""
    from ..sources.sampling import every_seconds

    span = float(kept[-1] - kept[0]) if len(kept) > 1 else 0.0
    if span <= 0:
        return np.sort(np.concatenate([kept, untracked])), "every frame"
    fps = (len(kept) - 1) / span
    extra = untracked[every_seconds(untracked, fps)] if len(untracked) else untracked
    return np.sort(np.concatenate([kept, extra])), f"{fps:.3g} frames/s"


def check_near_route(q_xy: np.ndarray, r_pos: np.ndarray, radius: float, where: str, geographic: bool) -> None:
    """Refuse (:class:`DatasetError`) query positions ``q_xy [N, 2]`` none of which lies within ``radius`` of a map
    position ``r_pos [R, 2]`` (metres): nothing could be scored. Positions not all finite are left to the caller."""
    from scipy.spatial import cKDTree

    ok = np.isfinite(r_pos).all(axis=1)
    if not len(q_xy) or not ok.any():
        return
    d, _ = cKDTree(r_pos[ok]).query(q_xy, k=1)
    if (d <= radius).any():
        return
    hint = "latitude and longitude swapped in the track?" if geographic else \
        "a track of another place, or in another frame than the map's positions?"
    raise DatasetError(f"no frame that {where} places ({len(q_xy)}) lies within the radius {radius:g} m of the "
                       f"map's route: the nearest is {float(d.min()):.0f} m away ({hint})")
