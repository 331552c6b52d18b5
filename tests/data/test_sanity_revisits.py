"""A reference that passes the same places twice while the ground truth knows one pass
(seqnet.data.sanity.revisits): said with the two stretches; silent when the ground truth knows both passes, on
routes without a revisit and at a stop."""

from __future__ import annotations

import numpy as np

from seqnet.data.positives import Positives
from seqnet.data.sanity import dataset_warnings
from seqnet.data.sanity.revisits import _same_place, revisited_reference
from seqnet.data.traverse import Dataset, Traverse


def places(n: int, seed: int = 0) -> np.ndarray:
    """``[n, 16]`` images of places along a route: each a little like the previous (repetitive scenery)."""
    rng = np.random.default_rng(seed)
    out = [rng.standard_normal(16)]
    for _ in range(n - 1):
        out.append(0.6 * out[-1] + 0.8 * rng.standard_normal(16))
    return np.array(out)


def make(ref: np.ndarray, r_pos=None, positives=None, n_query: int = 60) -> Dataset:
    rng = np.random.default_rng(1)
    qry = (ref[:n_query] + 0.5 * rng.standard_normal((n_query, ref.shape[1]))).astype(np.float32)
    r_pos = np.arange(len(ref), dtype=float)[:, None] if r_pos is None else r_pos
    return Dataset(Traverse(ref.astype(np.float32), r_pos, name="reference"),
                   Traverse(qry, np.arange(n_query, dtype=float)[:, None], name="query"), 1.0, name="d",
                   positives=positives)


def loop() -> np.ndarray:
    """60 places, then a second pass over places 0:30 (darker, a little noise): rows 60:90 show rows 0:30."""
    p = places(60)
    return np.concatenate([p, 0.85 * p[:30] + 0.02 * np.random.default_rng(2).standard_normal((30, 16))])


def first_pass(n_ref: int) -> Positives:
    return Positives.from_lists([[j for j in (i - 1, i, i + 1) if 0 <= j < n_ref] for i in range(60)])


def test_a_second_pass_unknown_to_the_ground_truth_is_said():
    [line] = dataset_warnings(make(loop()))  # frame numbers: row 60 is frame 60, far from frame 0
    assert line.startswith("d: reference frames 60:90 closely resemble frames 0:30 (")
    assert line.endswith("but the ground truth gives them no query in common: the reference passes the same places "
                         "twice? (top-1s on the other pass count as wrong; hint: give the reference's positions "
                         "(GPS), or list both passes in the positives)")
    assert revisited_reference(make(loop(), positives=first_pass(90))).startswith("reference frames 60:90")


def test_a_ground_truth_that_knows_both_passes_stays_silent():
    both = Positives.from_lists([[j for j in (i - 1, i, i + 1) if 0 <= j < 60]
                                 + [60 + j for j in (i - 1, i, i + 1) if 0 <= j < 30] for i in range(60)])
    assert revisited_reference(make(loop(), positives=both)) is None
    pos = np.r_[np.arange(60), np.arange(30)].astype(float)[:, None]  # GPS: the second pass at the first's places
    assert revisited_reference(make(loop(), r_pos=pos)) is None


def test_routes_without_a_revisit_stay_silent():
    assert dataset_warnings(make(places(90))) == []
    stop = places(90)
    stop[40:70] = stop[40] + 0.02 * np.random.default_rng(3).standard_normal((30, 16))  # a 30-frame stop
    assert revisited_reference(make(stop)) is None
    slow = np.repeat(places(30), 4, axis=0) + 0.05 * np.random.default_rng(4).standard_normal((120, 16))
    assert revisited_reference(make(slow)) is None  # a high frame rate: each place in view for 4 frames


def test_same_place_vs_a_loop():
    ds = make(loop(), positives=first_pass(90))
    i, j = np.array([0, 5, 10, 61, 70, 2]), np.array([1, 70, 30, 60, 5, 3])
    got = _same_place(ds, i, j)
    for k in range(len(i)):
        share = {q for q in range(60) if i[k] in ds.positives.of(q)} & {q for q in range(60) if j[k] in
                                                                          ds.positives.of(q)}
        assert got[k] == bool(share)
    pos = make(loop())
    assert _same_place(pos, i, j).tolist() == [abs(a - b) <= 2 for a, b in zip(i, j, strict=True)]


def test_clean_synthetic_dataset_is_silent(synth_dataset):
    assert revisited_reference(synth_dataset) is None
    for split in synth_dataset.splits:
        assert revisited_reference(synth_dataset.split(split)) is None


def test_eval_says_a_second_pass_too(tmp_path, caplog):
    """A dataset built before the check (or written by other means) is said at eval, per evaluated split."""
    import logging

    from seqnet.data.io import save_dataset
    from seqnet.eval.config import EvalConfig
    from seqnet.eval.evaluate import main as eval_main

    path = save_dataset(make(loop()), tmp_path / "ds")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        written = eval_main(EvalConfig(methods=("single",), radius=1.0), path, None)
    said = [w for w in written.data.get("warnings", []) if "closely resemble" in w]
    assert len(said) == 1 and said[0].startswith("reference frames 60:90 closely resemble frames 0:30"), said
