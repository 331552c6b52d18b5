"""Figures of the HTML report (:mod:`seqnet.report.html`): precision–recall curves, the distance
matrix with the ground truth and each method's top-1, and example queries beside their top-1.

Each returns a matplotlib figure (drawn by :func:`seqnet.report.tables.new_figure`, no pyplot) or PNG
bytes; nothing here writes files.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ImageError, SeqnetError
from ..core.tensors import spread
from ..data.traverse import Traverse
from ..metrics.recall import GroundTruth
from ..security.inputs import find_inside, open_input, within
from ..sequence.windows import window_starts
from .styles import TRUTH_COLOUR, family_legend, method_styles
from .tables import new_figure

MAX_TRUTH_POINTS = 20000  # ground-truth pairs drawn on the distance matrix at most


def truth_pairs(truth: GroundTruth, limit: int = MAX_TRUTH_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """``(query items, reference items)`` of correct pairs (explicit positives, or within the radius),
    evenly subsampled to at most ``limit``."""
    q, r = truth.pairs()
    keep = np.unique(np.linspace(0, len(q) - 1, min(limit, len(q))).astype(np.int64)) if len(q) else q
    return np.asarray(q)[keep], np.asarray(r)[keep]


def item_distances(query: np.ndarray, ref: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """L2 distances ``[m, r]`` of at most ``side`` evenly spaced rows of ``query [M, D]`` and ``ref [R, D]``,
    and the row / column indices used."""
    qi, ri = spread(len(query), side), spread(len(ref), side)
    a, b = np.asarray(query[qi], np.float64), np.asarray(ref[ri], np.float64)
    sq = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2 * a @ b.T
    return np.sqrt(np.maximum(sq, 0.0)), qi, ri


def top_one(ev: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(rows [n], cols [n])``: the evaluation's query and reference items (``ev.q_items``, ``ev.r_items``)
    of method ``name``'s top-1 matches that are among them (a single-frame method also ranks the frames
    without a full window: those are left out of the figure)."""
    view, top = ev.view(name), ev.retrieved[name][:, 0]
    ok = top >= 0
    q_frames, r_frames = view.q_items[ok], view.r_items[top[ok]]
    rows, cols = np.searchsorted(ev.q_items, q_frames), np.searchsorted(ev.r_items, r_frames)
    rows, cols = np.minimum(rows, len(ev.q_items) - 1), np.minimum(cols, len(ev.r_items) - 1)
    shown = (ev.q_items[rows] == q_frames) & (ev.r_items[cols] == r_frames)
    return rows[shown], cols[shown]


def matrix_figure(ev: Any, query: Traverse, reference: Traverse, side: int = 300,
                  methods: Sequence[str] | None = None) -> Any:
    """The single-image descriptor distance matrix of the evaluated items (downsampled to ``side``; the given
    matrix ``ev.matrix`` when the evaluation ran on one), the ground truth (orange: no method family's hue) and
    each method's top-1 (coloured dots) over it."""
    given = getattr(ev, "matrix", None)
    if given is not None:
        qi, ri = spread(len(ev.q_items), side), spread(len(ev.r_items), side)
        d = np.asarray(given[np.ix_(ev.q_items[qi], ev.r_items[ri])], np.float64)
    else:
        d, qi, ri = item_distances(query.descriptors[ev.q_items], reference.descriptors[ev.r_items], side)
    m, r = len(ev.q_items), len(ev.r_items)
    fig, ax = new_figure(8.5, 6.5)
    ax.imshow(d, cmap="gray", aspect="auto", interpolation="nearest", extent=(-0.5, r - 0.5, m - 0.5, -0.5))
    tq, tr = truth_pairs(ev.truth)
    ax.scatter(tr, tq, s=10, color=TRUTH_COLOUR, alpha=0.8, marker="s", linewidths=0, label="ground truth")
    names = list(methods or ev.retrieved)
    styles = method_styles(names)
    for name in names:
        rows, cols = top_one(ev, name)
        ax.scatter(cols, rows, s=6, color=styles[name]["color"], marker=styles[name]["marker"], linewidths=0,
                   label=name)
    ax.set_xlim(-0.5, r - 0.5)
    ax.set_ylim(m - 0.5, -0.5)
    from matplotlib.ticker import MaxNLocator  # items are whole numbers: no tick at 2.5

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(f"reference item ({r}; matrix shown at {len(ri)} columns)")
    ax.set_ylabel(f"query item ({m}; {len(qi)} rows)")
    leg = family_legend(ax, names, {n: f"{n} top-1" for n in names}, first=["ground truth"])
    for h in leg.legend_handles:
        if hasattr(h, "set_sizes"):
            h.set_sizes([30])  # a dot large enough to see its colour and marker
    ax.set_title("the given distances (dark = close)" if given is not None else
                 "single-image descriptor distances (dark = close)")
    return fig


@dataclasses.dataclass
class GalleryItem:
    """One example query: its window frames, the top-1 reference window frames, correct or not."""

    query: int  # row of the evaluation (query item index)
    query_frames: list[str]
    ref_frames: list[str]
    correct: bool
    confidence: float


def window_names(t: Traverse, frame: int, length: int, mode: str) -> list[str]:
    """Image names of the ``length``-frame window of ``frame`` in ``t`` (clamped inside its sequence)."""
    starts, _ = window_starts(len(t), length, mode, t.seq_bounds)
    first = int(np.clip(starts[frame], 0, max(len(t) - length, 0)))
    return [t.names[i] for i in range(first, min(first + length, len(t)))] if t.names else []


def pick_examples(correct: np.ndarray, has_positive: np.ndarray, n: int) -> list[int]:
    """Up to ``n`` query rows: failures first (two thirds of ``n`` at most, evenly spread along the
    queries), then correct ones (likewise), each group in query order."""
    wrong, right = np.flatnonzero(has_positive & ~correct), np.flatnonzero(has_positive & correct)
    n_wrong = min(len(wrong), max(n - min(len(right), n // 3), 0))
    n_right = min(len(right), n - n_wrong)

    return [int(wrong[i]) for i in spread(len(wrong), n_wrong)] + [int(right[i]) for i in spread(len(right), n_right)]


def gallery_png(item: GalleryItem, query_root: Path, ref_root: Path, gap: int = 2,
                notes: list[str] | None = None) -> bytes | None:
    """A PNG of the query window frames (top row) above the top-1 reference window frames; None when
    an image cannot be read or its name may not be read (:func:`gallery_image`), the reason added to
    ``notes``."""
    from PIL import Image

    rows = []
    for root, names in ((query_root, item.query_frames), (ref_root, item.ref_frames)):
        try:
            rows.append([gallery_image(root, n) for n in names])
        except SeqnetError as e:
            if notes is not None:
                notes.append(str(e))
            return None
    h = max(im.shape[0] for row in rows for im in row)
    w = max(sum(im.shape[1] + gap for im in row) for row in rows)
    canvas = np.full((2 * h + gap, w, 3), 255, np.uint8)
    for r, row in enumerate(rows):
        x = 0
        for im in row:
            canvas[r * (h + gap) : r * (h + gap) + im.shape[0], x : x + im.shape[1]] = im
            x += im.shape[1] + gap
    buf = io.BytesIO()
    Image.fromarray(canvas).save(buf, format="PNG")
    return buf.getvalue()


def gallery_image(root: Path, name: str) -> np.ndarray:
    """The image ``name`` (read from the dataset: untrusted) in the folder ``root``, decoded by the describers'
    reader (its formats only; size limit before decoding). ``name`` is found inside ``root`` by
    :func:`seqnet.security.inputs.find_inside` (relative to ``root``, or as the path a list file gave, e.g.
    ``../data/winter/img.png`` or an absolute one, when it lies in ``root``, or by its last parts, e.g.
    ``img.png``); nothing outside ``root`` is opened: the file is opened at its resolved path without following
    a link (``O_NOFOLLOW``), and refused when the opened file is not in ``root`` (a link swapped in meanwhile); a
    FIFO or device is never opened for reading."""
    from ..security.pictures import decode, open_image
    from ..sources.video import is_video

    if is_video(root) and Path(root).is_file():  # the frames of a video (from-video), named by their time
        return video_frame(Path(root), name)
    what = "gallery image name"
    path, real_root = find_inside(root, name, what, ImageError), os.path.realpath(root)
    real = os.path.realpath(path)
    if not within(real_root, real):
        raise ImageError(f"{what} {name!r} leads outside {root} (to {real}); not read")
    with open_input(real, "image", ImageError, follow=False) as f:
        opened = f"/proc/self/fd/{f.fileno()}"
        if os.path.islink(opened) and not within(real_root, real := os.path.realpath(opened)):  # where it leads
            raise ImageError(f"{what} {name!r} leads outside {root} (to {real}); not read")
        return decode(lambda: open_image(f), path)


def video_frame(video: Path, name: str) -> np.ndarray:
    """The frame of ``video`` named ``name`` (its time, as ``seqnet dataset from-video`` names frames), decoded as
    images are; a name that is no frame's is an :class:`ImageError`."""
    from ..security.pictures import decode
    from ..sources.video import VideoFrame

    v = _open_video(str(video))
    index = {n: i for i, n in enumerate(v.names)}.get(name)
    if index is None:
        raise ImageError(f"{video} has no frame named {name[:40]!r} (frames are named by their time in seconds)")
    frame = VideoFrame(v.file, index)
    return decode(frame.open, frame)


@functools.lru_cache(maxsize=4)
def _open_video(path: str) -> Any:
    """A video opened once for the report's frames (its frame names listed)."""
    from types import SimpleNamespace

    from ..sources.video import VideoFile, frame_name

    v = VideoFile(path)
    return SimpleNamespace(file=v, names=[frame_name(t) for t in v.times])
