"""A track's clock off by a constant time, seen in the answers: :func:`clock_offset` finds it, :func:`offset_note`
(``localize``, one video and its track) and :func:`dataset_offset_note` (``eval`` on a ``dataset from-video``
dataset: two videos, two tracks) say it with a hint that fits the track's times: numbers (seconds since the
video's start: shift the track's times; ``--video-start`` does not move them) or absolute times (the video's
clock: ``--video-start`` or its ``creation_time``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...data.trajectory import answer_positions

WRONG_SHARE = 0.2  # the offset is looked for when fewer answers than this share are correct


def clock_offset(frame_t: np.ndarray, est_xy: np.ndarray, track_t: np.ndarray, track_xy: np.ndarray,
                 min_frames: int = 10, max_dist: float | None = None) -> float | None:
    """The time offset (s) by which the estimates ``est_xy [N, 2]`` of the frames at ``frame_t [N]`` lag the track
    (fixes ``track_t [S]`` at ``track_xy [S, 2]``; negative: the estimates sit where the track was earlier), when
    it is near-constant: each estimate's nearest fix gives its track time, and their offsets from the frame times
    agree within a quarter of their median (and 1 s). None when too few frames or no common offset, or (``max_dist``)
    when most estimates lie farther than that from every fix: off the track, so its times cannot measure them (a
    query track kept for 15 frames, 3 s, gave "1.4 s" for answers 37 s along the route)."""
    ok = np.isfinite(est_xy).all(axis=1)
    if ok.sum() < min_frames or len(track_t) < 2:
        return None
    from scipy.spatial import cKDTree

    dist, near = cKDTree(track_xy).query(est_xy[ok], k=1)
    if max_dist is not None and not np.median(dist) <= max_dist:
        return None
    off = track_t[near] - frame_t[ok]
    med = float(np.median(off))
    spread = float(np.median(np.abs(off - med)))
    return med if abs(med) >= 1.0 and spread <= max(0.25 * abs(med), 1.0) else None


def offset_note(offset: float | None, numeric: bool = False) -> str | None:
    """What :func:`clock_offset` says of one video and its track, as a warning line (None: nothing to say);
    ``numeric``: the track's times are numbers (seconds since the video's start), which ``--video-start`` does not
    move: the hint is then to shift them."""
    if offset is None:
        return None
    d = abs(offset)
    way, fix = ("behind", "late") if offset < 0 else ("ahead of", "early")
    said = f"the estimates run {d:.1f} s {way} the track at nearly every frame"
    if numeric:
        late, shift = shift_hint(offset, "its")
        return (f"{said}: the track's times run {d:.1f} s {late} (hint: {shift}: numbers count seconds from the "
                "video's start, which --video-start does not move)")
    return f"{said}: is --video-start (or the video's creation_time) {d:.1f} s {fix}?"


def mostly_wrong(correct: np.ndarray) -> bool:
    """Whether answers ``correct [N]`` (bool) are enough (10 or more) and mostly wrong (under :data:`WRONG_SHARE`
    correct): when a clock offset is looked for."""
    return len(correct) >= 10 and bool(correct.mean() < WRONG_SHARE)


def dataset_offset_note(ds: Any, q_items: np.ndarray, r_items: np.ndarray, top1: np.ndarray) -> str | None:
    """The warning line when the query track of a ``dataset from-video`` dataset ``ds`` (a
    :class:`~seqnet.data.traverse.Dataset` whose ``extra`` has ``videos`` with tracks) runs a constant time off the
    reference's: most top-1 answers (``top1 [M]``: indices into ``r_items [R]``, reference frames; -1: none) of the
    query frames ``q_items [M]`` lie beyond the radius, but a constant time along the query frames' positions
    (each named by its video time). None otherwise, or for a dataset not from videos with tracks."""
    videos = (getattr(ds, "extra", None) or {}).get("videos")
    if not isinstance(videos, Mapping) or "positions" not in (videos.get("query") or {}) or not ds.query.names \
            or ds.position_unit != "metres" or ds.query.positions.shape[1] != 2:
        return None
    q, top = np.asarray(q_items, np.int64), np.asarray(top1, np.int64)
    q_xy = ds.query.positions[q]
    est_xy = answer_positions(ds.reference.positions[np.asarray(r_items, np.int64)], top)
    correct = np.linalg.norm(est_xy - q_xy, axis=1) <= ds.radius  # no answer (NaN): wrong
    if not mostly_wrong(correct):  # the usual case, before the names are parsed (once per method evaluated)
        return None
    try:
        q_times = np.asarray([float(ds.query.names[i]) for i in q], np.float64)
    except ValueError:
        return None
    order = np.argsort(q_times, kind="stable")
    offset = clock_offset(q_times, est_xy, q_times[order], q_xy[order], max_dist=ds.radius)
    if offset is None:
        return None
    d = abs(offset)
    late, shift = shift_hint(offset, "the query track's")
    kinds = {(videos.get(side) or {}).get("track_times") for side in ("query", "reference")}
    how = ("; numeric times count from the video's start: --video-start does not move them" if "seconds" in kinds
           else "; a video's creation_time off its track's clock? --video-start sets both videos' start"
           if "absolute" in kinds else "")
    return (f"most answers are wrong ({int(correct.sum())} of {len(correct)} correct), but they sit {d:.1f} s "
            f"{'ahead of' if offset > 0 else 'behind'} the query frames along the query track at nearly every frame: "
            f"the query track runs {d:.1f} s {late} against the reference's (hint: {shift}, or the opposite to the "
            f"reference's, and build the dataset again{how})")


def shift_hint(offset: float, whose: str) -> tuple[str, str]:
    """``("late", "subtract 2.0 s from <whose> times")`` for a track running ``offset`` s late (negative: early, and
    the hint is to add)."""
    d = abs(offset)
    return ("late", f"subtract {d:.1f} s from {whose} times") if offset > 0 else \
        ("early", f"add {d:.1f} s to {whose} times")
