"""Ground truth shifted against the images, without explicit positives (seqnet.eval.notices.shift): frame numbers
whose query recording starts N frames later or earlier (a few, or 50), and metric positions whose top-1s sit a
constant number of frames along the route (the reference's positions given for the query too); silent on correct
data; the offsets against a naive loop."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.config import EvalConfig
from seqnet.eval.evaluate import evaluate
from seqnet.eval.notices import shift_notice

METHODS = ("single", "raw+seqmatch")


def route(places: int = 160, shift: int = 0, metric: bool = False, aligned: bool = True, seed: int = 0) -> Dataset:
    """One reference frame per place; query frame k shows place k + ``shift`` but is numbered (or placed) as
    reference frame k: frame numbers (``aligned``: two folders paired by order) or metric positions 10 m apart
    (the query's row for row the reference's)."""
    rng = np.random.default_rng(seed)
    ref = rng.standard_normal((places, 16)).astype(np.float32)
    shown = np.arange(places - max(0, shift)) + shift  # the places the query frames show (< 0: before the reference)
    outside = rng.standard_normal((places, 16)).astype(np.float32)
    qry = np.where((shown >= 0)[:, None], ref[np.maximum(shown, 0)], outside[:len(shown)])
    qry = qry + 0.05 * rng.standard_normal(qry.shape).astype(np.float32)
    at = (lambda k: np.stack([10.0 * k, np.zeros(len(k))], axis=1)) if metric else (lambda k: k[:, None] * 1.0)
    frames = np.arange(len(shown))
    return Dataset(Traverse(ref, at(np.arange(places)), name="reference"), Traverse(qry, at(frames), name="query"),
                   radius=12.0 if metric else 1.0, name="route",
                   extra={"ground_truth": "frames"} if aligned and not metric else {})


@pytest.mark.parametrize("shift", [3, 50, -3])
def test_frame_numbers_whose_query_starts_later_or_earlier_are_said(shift):
    said = shift_notice(evaluate(route(shift=shift), EvalConfig(methods=METHODS)))
    d = abs(shift)
    assert said is not None and said.startswith(f"the top-1s look shifted by {shift:+d} frames: "), said
    assert f"lie exactly {d} frames {'after' if shift > 0 else 'before'} the query's own frame number" in said
    assert f"the query recording starts {d} frames {'later' if shift > 0 else 'earlier'}" in said
    assert f"drop the first {d} frames of the {'reference' if shift > 0 else 'query'} folder" in said
    assert "(single, raw+seqmatch)" in said


def test_a_frame_column_gets_a_hint_on_the_numbers():
    said = shift_notice(evaluate(route(shift=4, aligned=False), EvalConfig(methods=METHODS)))
    assert said is not None and "hint: add 4 to the query's frame numbers" in said, said


def test_metric_positions_a_constant_number_of_frames_off_are_said():
    said = shift_notice(evaluate(route(shift=50, metric=True), EvalConfig(methods=METHODS)))
    assert said is not None and said.startswith("the query positions look shifted along the route: "), said
    assert "lie exactly 50 reference frames after the reference nearest the query's position" in said


def test_correct_frames_and_positions_stay_silent(synth_dataset):
    for ds in (route(), route(metric=True), route(aligned=False), synth_dataset, synth_dataset.split("test")):
        ev = evaluate(ds, EvalConfig(methods=METHODS))
        assert shift_notice(ev) is None
    # a shift of one frame is within the radius of 1 frame: nothing wrong to say
    assert shift_notice(evaluate(route(shift=1), EvalConfig(methods=METHODS))) is None


def test_route_offsets_match_a_naive_loop(synth_dataset):
    from seqnet.eval.notices.shift import route_offsets

    conf = EvalConfig(methods=("single",), ks=(1, 5))
    for ds in (route(shift=5, metric=True, places=60), route(shift=-4, places=60), synth_dataset):
        ev = evaluate(ds, conf)
        view, top = ev.view("single"), ev.retrieved["single"][:, 0]
        t = view.truth
        want = []
        for m in range(len(t.q_pos)):
            d = np.linalg.norm(t.r_pos - t.q_pos[m], axis=1)
            if top[m] < 0 or not (d <= t.radius).any():
                continue
            want.append(0 if d[top[m]] <= t.radius else int(view.r_items[top[m]] - view.r_items[int(np.argmin(d))]))
        assert route_offsets(view, top).tolist() == want
