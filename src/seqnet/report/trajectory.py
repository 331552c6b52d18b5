"""The trajectory plot of a localised track: where each frame was recognised, on the reference route.

Left: the reference route (grey), the query's true path (blue, dashed, with ground truth) and each estimate
placed on the route, green when correct (within the radius) and red when wrong, a thin red line from the true
position to a wrong estimate (fainter the more there are); without ground truth the estimates are coloured by
confidence. Right (with ground truth): the error of each estimate in metres over the query frames, the radius
dashed. Positions in frames (a frame-aligned dataset) are drawn as the estimated reference frame over the query
frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..data.trajectory import TrackView
from .tables import new_figure, save_figure

GREEN, RED, GREY, BLUE = "#2ca02c", "#d62728", "#9a9a9a", "#1f77b4"


def errors(view: TrackView) -> np.ndarray:
    """``[Nq]`` distance (in the positions' unit) from each frame's true position to its estimate; NaN where
    either is missing."""
    if view.truth is None:
        return np.full(len(view.estimate), np.nan)
    return np.linalg.norm(np.asarray(view.truth, np.float64) - view.estimate, axis=1)


def _route(ax: Any, view: TrackView) -> None:
    """The 2-D panel: route, true path, estimates, wrong-estimate lines."""
    o = np.nanmin(view.ref, axis=0) if len(view.ref) else np.zeros(2)
    ref, est = view.ref - o, view.estimate - o
    ax.plot(ref[:, 0], ref[:, 1], color=GREY, lw=4, alpha=0.6, label="reference route", zorder=1)
    ax.plot(*ref[0], marker="s", color="k", ms=6, ls="", label="route start", zorder=4)
    if view.truth is None:
        _by_confidence(ax, est[:, 0], est[:, 1], view.confidence, 12)
    else:
        true = np.asarray(view.truth, np.float64) - o
        ax.plot(true[:, 0], true[:, 1], color=BLUE, lw=1, ls="--", label="query (true path)", zorder=2)
        ok = np.asarray(view.correct, bool)
        known = np.asarray(view.has_positive, bool) if view.has_positive is not None else np.isfinite(true[:, 0])
        wrong = known & ~ok & np.isfinite(est[:, 0])
        from matplotlib.collections import LineCollection

        segments = np.stack([true[wrong], est[wrong]], axis=1)  # [W, 2, 2]: true position -> wrong estimate
        alpha = min(0.5, 40.0 / max(len(segments), 1))  # many wrong answers: faint lines, the route stays legible
        ax.add_collection(LineCollection(segments, colors=RED, linewidths=0.5, alpha=alpha, zorder=0))
        for mask, colour, label in ((known & ok, GREEN, "correct"), (wrong, RED, "wrong"),
                                    (~known, GREY, "no ground truth")):
            if mask.any():
                ax.scatter(est[mask, 0], est[mask, 1], color=colour, s=12, zorder=3,
                           label=f"{label} ({int(mask.sum())})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"easting − {o[0]:.0f} (m)")
    ax.set_ylabel(f"northing − {o[1]:.0f} (m)")
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)


def _by_confidence(ax: Any, x: np.ndarray, y: np.ndarray, confidence: np.ndarray, size: float) -> None:
    """Estimates ``(x, y) [N]`` coloured by ``confidence [N]`` (NaN: unanswered frames, not drawn), a colour bar,
    and a legend entry in the colour of the median confidence (a scatter's own entry takes its first point's
    colour: none when the first frames are unanswered)."""
    conf = np.asarray(confidence, np.float64)
    shown = np.isfinite(conf) & np.isfinite(np.asarray(x, np.float64)) & np.isfinite(np.asarray(y, np.float64))
    sc = ax.scatter(np.asarray(x)[shown], np.asarray(y)[shown], c=conf[shown], cmap="viridis", s=size, zorder=3)
    ax.figure.colorbar(sc, ax=ax, label="confidence", shrink=0.8)
    mid = sc.cmap(sc.norm(float(np.median(conf[shown])))) if shown.any() else GREY
    ax.scatter([], [], color=mid, s=size, label=f"estimate ({int(shown.sum())}; colour: confidence)")


def _frames(ax: Any, view: TrackView) -> None:
    """The 1-D panel: estimated reference frame over the query frame."""
    q = np.arange(len(view.estimate))
    if view.truth is not None:
        ax.plot(q, np.asarray(view.truth)[:, 0], color=BLUE, lw=1, ls="--", label="true reference frame")
        ok = np.asarray(view.correct, bool)
        for mask, colour, label in ((ok, GREEN, "correct"), (~ok, RED, "wrong")):
            ax.scatter(q[mask], view.estimate[mask, 0], color=colour, s=8, label=label)
    else:
        _by_confidence(ax, q, view.estimate[:, 0], view.confidence, 8)
    ax.set_xlabel("query frame")
    ax.set_ylabel("reference frame")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)


def _errors(ax: Any, view: TrackView) -> None:
    err = errors(view)
    q = np.arange(len(err))
    ok = np.asarray(view.correct, bool)
    ax.scatter(q[ok], err[ok], color=GREEN, s=6, label="correct")
    ax.scatter(q[~ok], err[~ok], color=RED, s=6, label="wrong")
    ax.axhline(view.radius, color="k", ls="--", lw=1, label=f"radius {view.radius:g} m")
    if np.isfinite(err).any() and np.nanmax(err) > 20 * view.radius:
        ax.set_yscale("symlog", linthresh=view.radius)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("query frame")
    ax.set_ylabel("error (m)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)


def trajectory_figure(view: TrackView, title: str = "") -> Any:
    """The figure of a :class:`TrackView` (see the module docstring)."""
    metric = view.ref.shape[1] == 2
    both = metric and view.truth is not None
    fig, axes = new_figure(12 if both else 7, 6, 2 if both else 1)
    ax = axes[0] if both else axes
    (_route if metric else _frames)(ax, view)
    if both:
        _errors(axes[1], view)
    counted = None if view.has_positive is None else view.has_positive & np.isfinite(view.estimate[:, 0])
    if view.correct is not None and counted is not None and counted.any():  # as the summary: frames answered
        r1 = float(np.asarray(view.correct)[counted].mean())
        title = f"{title}  R@1 {r1:.3f} of {int(counted.sum())} frames answered with ground truth".strip()
    if title:
        fig.suptitle(title, parse_math=False)
    return fig


def write_trajectory(view: TrackView, path: str | Path, title: str = "") -> Path:
    """Write the trajectory figure of ``view`` to the PNG ``path`` (atomically)."""
    return save_figure(trajectory_figure(view, title), path)
