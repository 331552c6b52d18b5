"""Every method's R@K at the level of a random ranking (seqnet.eval.notices.chance): separately fitted PCAs or
another describer on one side are said, naming the missing provenance; poor but real methods and correct data stay
silent; a random ranking's R@K and the positives' counts against naive loops."""

from __future__ import annotations

import dataclasses
import json
import logging
from math import comb

import numpy as np

from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.eval.config import EvalConfig
from seqnet.eval.evaluate import evaluate
from seqnet.eval.evaluate import main as eval_main

METHODS = ("single", "raw+seqmatch")
KS = EvalConfig().ks


def pca(a: np.ndarray, k: int) -> np.ndarray:
    """``a [N, D]`` reduced to ``[N, k]`` by a PCA fitted on ``a`` alone."""
    centred = a - a.mean(axis=0)
    return (centred @ np.linalg.svd(centred, full_matrices=False)[2][:k].T).astype(np.float32)


def separate_pcas(ds):
    """``ds`` with each traverse reduced by its own PCA and no provenance (an own pipeline's bug)."""
    return dataclasses.replace(ds, reference=ds.reference.with_descriptors(pca(ds.reference.descriptors, 16)),
                               query=ds.query.with_descriptors(pca(ds.query.descriptors, 16)))


def test_separately_fitted_pcas_are_said_with_the_missing_provenance(tmp_path, caplog):
    ds = separate_pcas(make_synthetic(places=200, dim=32, noise=0.05, seed=1))
    save_dataset(ds, tmp_path / "ds")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        eval_main(EvalConfig(methods=METHODS, split="all"), tmp_path / "ds", tmp_path / "out")
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    said = [w for w in results["warnings"] if w.startswith("every method's R@K is what a random ranking gives")]
    assert len(said) == 1, results["warnings"]
    assert "(single: R@1 " in said[0] and "the reference and query descriptors may not be comparable" in said[0]
    assert "PCAs fitted on each traverse separately" in said[0]
    assert "neither descriptor file records how it was made" in said[0]
    assert "fit any PCA on both traverses at once" in said[0]
    assert any(said[0] in r.getMessage() for r in caplog.records)


def test_another_describer_on_one_side_is_said():
    from seqnet.eval.notices.chance import chance_notice

    ds = make_synthetic(places=200, dim=32, noise=0.05, seed=1)
    turn = np.linalg.qr(np.random.default_rng(0).standard_normal((32, 32)))[0]
    ds = dataclasses.replace(ds, query=ds.query.with_descriptors((ds.query.descriptors @ turn).astype(np.float32),
                                                                 ds.query.provenance))
    said = chance_notice(evaluate(ds, EvalConfig(methods=METHODS, split="all")), KS)
    assert said is not None and "their provenance is one, so the ground truth may rather not belong" in said, said


def test_poor_and_correct_methods_stay_silent(synth_dataset):
    from seqnet.eval.notices.chance import chance_notice

    for ds in (synth_dataset, synth_dataset.split("test"), make_synthetic(places=200, dim=32, noise=4.0, seed=1),
               make_synthetic(places=200, dim=32, noise=0.05, seed=1)):
        ev = evaluate(ds, EvalConfig(methods=METHODS))
        assert chance_notice(ev, KS) is None
        assert not any("random ranking" in w for w in ev.results.get("warnings", []))


def test_random_recall_matches_the_counting_formula():
    from seqnet.eval.notices.chance import random_recall

    counts = np.array([0, 1, 2, 3, 7, 19, 20])
    for n, k in ((20, 1), (20, 5), (20, 19), (20, 20), (20, 100), (300, 100)):
        want = [1 - comb(n - c, k) / comb(n, k) if n - c >= k else 1.0 for c in counts]
        if k >= n:
            want = [float(c > 0) for c in counts]
        np.testing.assert_allclose(random_recall(counts, n, k), want, atol=1e-9)


def test_positive_counts_match_a_naive_loop(synth_dataset):
    from seqnet.eval.notices.chance import positive_counts

    frames = dataclasses.replace(synth_dataset, reference=dataclasses.replace(
        synth_dataset.reference, positions=np.arange(len(synth_dataset.reference))[:, None] * 1.0),
        query=dataclasses.replace(synth_dataset.query, positions=np.arange(len(synth_dataset.query))[:, None] * 1.0),
        radius=2.0, position_unit="frames")
    for ds in (synth_dataset, frames):
        view = evaluate(ds, EvalConfig(methods=("single",), ks=(1,))).view("single")
        t = view.truth
        want = [int((np.linalg.norm(t.r_pos - t.q_pos[m], axis=1) <= t.radius).sum()) for m in range(len(t.q_pos))]
        assert positive_counts(view).tolist() == want
