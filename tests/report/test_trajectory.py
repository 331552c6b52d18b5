"""The trajectory plot and the worst / best pairs: built from a track view, with and without ground truth."""

from __future__ import annotations

import numpy as np

from seqnet.data.trajectory import TrackView
from seqnet.report.places import pair_png, pick_pairs
from seqnet.report.trajectory import errors, trajectory_figure


def _view(truth: bool, dims: int = 2) -> TrackView:
    t = np.linspace(0, 3, 40)
    ref = np.stack([np.cos(t), np.sin(t)], 1)[:, :dims] * 500
    est = ref[np.r_[np.arange(30), np.full(10, 5)]].copy()
    est[0] = np.nan  # no answer
    correct = np.r_[np.zeros(1, bool), np.ones(29, bool), np.zeros(10, bool)]
    return TrackView(ref, est, ref.copy() if truth else None, correct if truth else None,
                     np.r_[np.zeros(1, bool), np.ones(39, bool)] if truth else None, np.linspace(0, 1, 40),
                     "metres" if dims == 2 else "frames", 25.0)


def test_errors_and_picks():
    v = _view(True)
    err = errors(v)
    assert np.isnan(err[0]) and np.allclose(err[1:30], 0) and (err[30:] > 25).all()
    worst, best = pick_pairs(v, 3)
    assert worst == [39, 38, 37] and best == [29, 28, 27]  # farthest wrong; most confident correct


def test_figures_draw_each_kind():
    for view, panels in ((_view(True), 2), (_view(False), 2), (_view(True, 1), 1)):  # colour bar: a second axes
        fig = trajectory_figure(view, "t")
        assert len(fig.axes) == panels
    title = trajectory_figure(_view(True)).texts[0].get_text()
    assert "R@1 0.744 of 39 frames answered" in title  # 29 correct of the 39 answered with ground truth


def test_pair_png():
    png = pair_png([np.zeros((16, 32, 3), np.uint8), np.full((8, 32), 200, np.uint8)])
    from io import BytesIO

    from PIL import Image

    assert Image.open(BytesIO(png)).size == (32 * 2 + 3, 16)


def test_without_ground_truth_the_estimates_have_a_legend_colour_and_a_colour_bar():
    for dims in (1, 2):  # frames (a frame-aligned dataset) and metres
        view = _view(False, dims)
        view.confidence[:5] = np.nan  # the first frames unanswered, as a stream's are: the scatter's first point
        fig = trajectory_figure(view)
        assert len(fig.axes) == 2 and fig.axes[1].get_ylabel() == "confidence", dims
        legend = fig.axes[0].get_legend()
        entry = next(h for h, t in zip(legend.legend_handles, legend.get_texts(), strict=True)
                     if t.get_text().startswith("estimate"))
        assert entry.get_facecolor()[0][3] > 0, dims  # visible (an empty marker was drawn before)
        assert legend.get_texts()[-1].get_text() == "estimate (35; colour: confidence)"
