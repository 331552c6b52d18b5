"""Ground truth that looks shifted against the images: the top-1 answers of every method evaluated, pooled, cluster
at one constant offset (:func:`seqnet.metrics.shift.shifted_offset`, reaching as far as the reference route is
long) from what the ground truth calls correct. Explicit positives: from the nearest listed positive (a 1-based
file, an off-by-N list). A radius: from the reference frame nearest the query's position, in reference frames along
the route, counting a top-1 within the radius as on it — frame numbers (``--frame-aligned``, a ``frame`` column)
when the query recording starts N frames later or earlier than the reference's, metric positions when the query's
positions belong to other frames than its images (the reference's positions file given for the query too, a
clock offset)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...methods.route import nearest_position
from ...metrics.shift import shifted_offset, top1_offsets
from ..evaluation import Evaluation, ItemView


def shift_notice(ev: Evaluation) -> str | None:
    """The line saying that the ground truth looks shifted against the images (the module), or None: explicit
    positives (:func:`positives_line`), else frame numbers (:func:`frames_line`) or metric positions
    (:func:`positions_line`)."""
    pooled, names, explicit, reach = [], [], False, 0
    for name, retrieved in ev.retrieved.items():
        view = ev.view(name)
        if retrieved.ndim != 2 or retrieved.shape[1] == 0 or len(view.r_items) == 0:
            continue
        explicit = view.truth.positives is not None
        pooled.append(positive_offsets(view, retrieved[:, 0]) if explicit else route_offsets(view, retrieved[:, 0]))
        names.append(name)
        reach = max(reach, len(view.r_items) - 1)
    offsets = np.concatenate(pooled) if pooled else np.zeros(0, np.int64)
    o = shifted_offset(offsets, reach=reach) if len(offsets) else None
    if o is None:
        return None
    n, hits = int((offsets == o).sum()), int((offsets == 0).sum())
    if explicit:
        return positives_line(o, n, len(offsets), hits, names)
    unit = getattr(ev.dataset, "position_unit", None) or ("frames" if ev.q_pos.shape[1] == 1 else "metres")
    if unit == "frames":
        return frames_line(o, n, len(offsets), hits, names, (getattr(ev.dataset, "extra", None) or {}))
    return positions_line(o, n, len(offsets), hits, names)


def positive_offsets(view: ItemView, top: np.ndarray) -> np.ndarray:
    """``[Q]`` int64: the top-1 (``top [M]``: indices into ``view.r_items``; < 0: none) of each query with a listed
    positive minus its nearest listed positive, in reference frames (:func:`seqnet.metrics.shift.top1_offsets`)."""
    r_items = np.asarray(view.r_items, dtype=np.int64)
    top = np.asarray(top, dtype=np.int64)
    top1 = np.where(top >= 0, r_items[np.maximum(top, 0)], -1)
    q, r = view.truth.positives.pairs()
    return top1_offsets(top1, q, r_items[r])


def route_offsets(view: ItemView, top: np.ndarray) -> np.ndarray:
    """``[Q]`` int64, for each query with a reference within the radius and a top-1 (``top [M]``: indices into
    ``view.r_items``; < 0: none): 0 when its top-1 is within the radius, else the top-1's reference frame minus
    the frame of the reference nearest the query's position (frames along the route)."""
    t = view.truth
    top = np.asarray(top, dtype=np.int64)
    keep = (top >= 0) & t.has_positive()
    if not keep.any():
        return np.zeros(0, np.int64)
    q_pos, r_pos = np.asarray(t.q_pos, np.float64)[keep], np.asarray(t.r_pos, np.float64)
    q_pos, r_pos = q_pos - r_pos[:1], r_pos - r_pos[:1]  # about one point: UTM coordinates in float64
    top = top[keep]
    correct = np.linalg.norm(r_pos[top] - q_pos, axis=1) <= t.radius
    r_items = np.asarray(view.r_items, dtype=np.int64)
    return np.where(correct, 0, r_items[top] - r_items[nearest_position(r_pos, q_pos)[1].astype(np.int64)])


def positives_line(o: int, n: int, total: int, hits: int, names: list[str]) -> str:
    """The line for explicit positives shifted by ``o``: ``n`` of ``total`` top-1s at it, ``hits`` on a positive."""
    side = "before" if o < 0 else "after"
    return (f"positives look shifted by {o:+d}{' (1-based indices?)' if o == -1 else ''}: {n} of {total} "
            f"top-1 answers ({', '.join(names)}) lie exactly {abs(o)} reference frame{'s' if abs(o) > 1 else ''} "
            f"{side} a listed positive, against {hits} on one; hint: check the positives file's indices (0-based: "
            "reference 0 is the first reference image)")


def frames_line(o: int, n: int, total: int, hits: int, names: list[str], extra: dict[str, Any]) -> str:
    """The line for frame-number ground truth whose top-1s lie ``o`` frames from the query's own frame number
    (``extra``: the dataset's, whose ``ground_truth`` ``frames`` says the folders were paired by order)."""
    d, later = abs(o), o > 0
    frames = f"{d} frame{'s' if d > 1 else ''}"
    first = "reference" if later else "query"
    fix = (f"drop the first {frames} of the {first} folder" if extra.get("ground_truth") == "frames" else
           f"{'add' if later else 'subtract'} {d} {'to' if later else 'from'} the query's frame numbers")
    return (f"the top-1s look shifted by {o:+d} frames: {n} of {total} top-1 answers ({', '.join(names)}) lie "
            f"exactly {frames} {'after' if later else 'before'} the query's own frame number, against {hits} within "
            f"the radius: the query recording starts {frames} {'later' if later else 'earlier'} along the route than "
            f"the reference's? hint: {fix} and build the dataset again, or give positions (easting,northing or "
            "lat,lon columns) instead of frame numbers")


def positions_line(o: int, n: int, total: int, hits: int, names: list[str]) -> str:
    """The line for metric ground truth whose top-1s lie ``o`` reference frames along the route from the reference
    nearest the query's position."""
    d = abs(o)
    return (f"the query positions look shifted along the route: {n} of {total} top-1 answers ({', '.join(names)}) "
            f"lie exactly {d} reference frame{'s' if d > 1 else ''} {'after' if o > 0 else 'before'} the reference "
            f"nearest the query's position, against {hits} within the radius: are the query positions those of other "
            "frames (the reference's positions file given for the query too, or a clock or frame offset between the "
            "query images and their positions)? hint: check the query's positions file against its images and build "
            "the dataset again")
