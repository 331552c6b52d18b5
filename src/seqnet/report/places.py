"""Where the queries were recognised, in the report: the trajectory plot (positions in metres) and, when the
frames can be read (image folders, or the videos: ``--images-query VIDEO --images-ref VIDEO``), pair images of
the worst and best queries: the query frame | the matched reference frame | the true reference frame (the one
nearest to the query's position).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import SeqnetError
from ..data.trajectory import TrackView, answer_positions
from ..data.traverse import Dataset
from .figures import gallery_image
from .tables import figure_png
from .trajectory import errors, trajectory_figure

PAIRS = 4  # worst and best queries shown each


def best_method(ev: Any) -> str:
    """The method of the best R@1."""
    methods = ev.results["methods"]
    return max(methods, key=lambda m: methods[m].get("recall@1", -1.0))


def evaluation_view(ev: Any, ds: Dataset, name: str) -> TrackView:
    """The :class:`TrackView` of method ``name``'s top-1 answers over the evaluated queries of ``ds``."""
    view = ev.view(name)
    top = ev.retrieved[name][:, 0]
    est = answer_positions(ds.reference.positions[view.r_items], top)
    correct = view.truth.hits(ev.retrieved[name][:, :1])[:, 0]
    return TrackView(np.asarray(ds.reference.positions, np.float64), est,
                     np.asarray(ds.query.positions[view.q_items], np.float64), correct, view.truth.has_positive(),
                     np.asarray(ev.confidence.get(name, np.zeros(len(top))), np.float64), ds.position_unit,
                     float(ev.results["config"].get("radius") or ds.radius))


def has_route(ds: Dataset) -> bool:
    """Whether the dataset's positions are metres in two dimensions (a route to draw)."""
    return ds.position_unit == "metres" and ds.reference.positions.ndim == 2 and ds.reference.positions.shape[1] == 2


def trajectory_png(ev: Any, ds: Dataset) -> tuple[bytes, str]:
    """``(PNG, method)``: the trajectory plot of the best method's answers."""
    name = best_method(ev)
    return figure_png(trajectory_figure(evaluation_view(ev, ds, name), name)), name


def pick_pairs(view: TrackView, n: int = PAIRS) -> tuple[list[int], list[int]]:
    """``(worst, best)``: up to ``n`` wrong queries of the largest error and ``n`` correct ones of the highest
    confidence (rows of ``view``)."""
    err = errors(view)
    known = np.asarray(view.has_positive, bool) & np.isfinite(err)
    ok = np.asarray(view.correct, bool)
    wrong, right = np.flatnonzero(known & ~ok), np.flatnonzero(known & ok)
    return (wrong[np.argsort(-err[wrong], kind="stable")][:n].tolist(),
            right[np.argsort(-view.confidence[right], kind="stable")][:n].tolist())


def pair_png(frames: list[np.ndarray], gap: int = 3) -> bytes:
    """The frames side by side (on white, top-aligned) as PNG bytes."""
    import io

    from PIL import Image

    h, w = max(f.shape[0] for f in frames), sum(f.shape[1] for f in frames) + gap * (len(frames) - 1)
    canvas = np.full((h, w, 3), 255, np.uint8)
    x = 0
    for f in frames:
        canvas[: f.shape[0], x : x + f.shape[1]] = f if f.ndim == 3 else f[..., None]
        x += f.shape[1] + gap
    buf = io.BytesIO()
    Image.fromarray(canvas).save(buf, format="PNG")
    return buf.getvalue()


def pair_items(ev: Any, ds: Dataset, query_root: Path, ref_root: Path) -> tuple[str, list[tuple[bool, bytes | None,
                                                                                                str]]]:
    """``(method, [(correct, PNG or None, caption)])``: the worst and best queries of the best method, each the
    query frame | the matched reference frame | the true reference frame (None: not readable, said in the
    caption)."""
    name = best_method(ev)
    tv, view = evaluation_view(ev, ds, name), ev.view(name)
    top, err = ev.retrieved[name][:, 0], errors(tv)
    worst, best = pick_pairs(tv)
    items = []
    for label, rows in (("worst", worst), ("best", best)):
        for row in rows:
            qi, mi = int(view.q_items[row]), int(view.r_items[top[row]])
            ti = int(np.argmin(np.linalg.norm(ds.reference.positions - ds.query.positions[qi], axis=1)))
            names = (ds.query.names[qi], ds.reference.names[mi], ds.reference.names[ti])
            caption = (f"{label}: query {names[0]} → {names[1]} ({float(err[row]):.0f} {ds.position_unit} off; true "
                       f"place {names[2]})")
            try:
                png = pair_png([gallery_image(r, n) for r, n in zip((query_root, ref_root, ref_root), names,
                                                                     strict=True)])
            except SeqnetError as e:
                png, caption = None, f"{caption} (pictures left out: {str(e)[:300]})"
            items.append((label == "best", png, caption))
    return name, items
