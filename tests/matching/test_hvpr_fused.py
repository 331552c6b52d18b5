"""Fused HVPR re-ranking (score = matcher / L_m + λ · shortlist distance) against a naive loop, and the
``hvpr-fused`` method name."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.matching.hvpr import hvpr, rerank
from seqnet.methods.grammar import parse_method, valid_methods
from seqnet.sequence.model import SeqNet


def naive_fused(sq, sr, q, r, L, q_starts, r_starts, top_k, lam, reverse=False):
    """The fused HVPR ranking by plain loops: shortlist by distance (ties: lower index), then sort the
    shortlist by sum-of-frame-distances / L + λ · shortlist distance (stable)."""
    items, scores = [], []
    for m in range(len(sq)):
        d = [float(np.linalg.norm(sq[m] - sr[j])) for j in range(len(sr))]
        short = sorted(range(len(sr)), key=lambda j: (d[j], j))[:top_k]
        s = []
        for j in short:
            a, b = q_starts[m], r_starts[j]
            seq = sum(float(np.linalg.norm(q[a + t] - r[b + (L - 1 - t if reverse else t)])) for t in range(L))
            s.append(seq / L + lam * d[j])
        order = sorted(range(len(short)), key=lambda i: s[i])
        items.append([short[i] for i in order])
        scores.append([s[i] for i in order])
    return np.array(items), np.array(scores)


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("lam", [0.25, 1.0, 10.0])
def test_fused_hvpr_vs_loop(rng, reverse, lam):
    q, r = rng.standard_normal((20, 4)), rng.standard_normal((25, 4))
    L = 3
    q_starts, r_starts = np.arange(0, 18, 2), np.arange(0, 23)
    sq, sr = rng.standard_normal((len(q_starts), 6)), rng.standard_normal((len(r_starts), 6))
    matcher = "seqmatch-rev" if reverse else "seqmatch"
    scores, items = hvpr(sq, sr, q, r, L, q_starts, r_starts, top_k=6, matcher=matcher, device="cpu", fuse=lam)
    n_items, n_scores = naive_fused(sq, sr, q, r, L, q_starts, r_starts, 6, lam, reverse)
    np.testing.assert_array_equal(items, n_items)
    np.testing.assert_allclose(scores, n_scores, rtol=1e-9)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), top_k=st.integers(1, 12), lam=st.floats(0.01, 5.0), L=st.integers(1, 4))
def test_fused_hvpr_vs_loop_random(seed, top_k, lam, L):
    g = np.random.default_rng(seed)
    q, r = g.standard_normal((12, 3)), g.standard_normal((10, 3))
    q_starts, r_starts = np.arange(12 - L + 1), np.arange(10 - L + 1)
    sq, sr = g.standard_normal((len(q_starts), 5)), g.standard_normal((len(r_starts), 5))
    scores, items = hvpr(sq, sr, q, r, L, q_starts, r_starts, top_k=top_k, device="cpu", fuse=lam)
    n_items, n_scores = naive_fused(sq, sr, q, r, L, q_starts, r_starts, top_k, lam)
    k = min(top_k, len(r_starts))
    np.testing.assert_allclose(scores[:, :k], n_scores, rtol=1e-9)
    np.testing.assert_array_equal(items[:, :k], n_items)  # Gaussian data: no ties


def test_fuse_zero_is_the_papers_hvpr_and_large_fuse_is_the_shortlist(rng):
    q, r = rng.standard_normal((15, 4)), rng.standard_normal((15, 4))
    starts = np.arange(13)
    sq, sr = rng.standard_normal((13, 6)), rng.standard_normal((13, 6))
    plain = hvpr(sq, sr, q, r, 3, starts, starts, top_k=5, device="cpu")
    np.testing.assert_array_equal(hvpr(sq, sr, q, r, 3, starts, starts, top_k=5, device="cpu", fuse=0.0)[1], plain[1])
    from seqnet.search.knn import knn

    _, shortlist = knn(sq, sr, 5, device="cpu")
    heavy = hvpr(sq, sr, q, r, 3, starts, starts, top_k=5, device="cpu", fuse=1e6)[1]
    np.testing.assert_array_equal(heavy, shortlist)  # λ → ∞: the S_L order
    with pytest.raises(ConfigError, match="fuse must be"):
        hvpr(sq, sr, q, r, 3, starts, starts, fuse=-1.0)
    with pytest.raises(ConfigError, match="prior must have"):
        rerank(q, r, 3, starts, starts, shortlist, prior=np.zeros((13, 4)))


def test_hvpr_fused_method_names():
    m = parse_method("hvpr-fused")
    assert (m.kind, m.shortlist, m.rerank, m.fused) == ("hvpr", "seqnet", "s1+seqmatch", True)
    assert m.summary() == {"kind": "hvpr", "shortlist": "seqnet", "rerank": "s1+seqmatch", "fused": True}
    m = parse_method("hvpr-fused:s1+seqmatch-rev")
    assert (m.rerank, m.fused, m.models()) == ("s1+seqmatch-rev", True, {"seqnet", "s1"})
    assert not parse_method("hvpr").fused and "fused" not in parse_method("hvpr").summary()
    assert "hvpr-fused" in valid_methods()
    with pytest.raises(ConfigError, match="re-ranker"):
        parse_method("hvpr-fused:nope")
    with pytest.raises(ConfigError, match="fuse_weight"):
        EvalConfig(fuse_weight=-0.5)


def test_evaluate_hvpr_fused(test_split_fused):
    ds = test_split_fused
    torch.manual_seed(0)
    models = {"seqnet": SeqNet(16, 8, 5, 3), "s1": SeqNet(16, 8, 1, 1)}
    conf = EvalConfig(methods=("hvpr", "hvpr-fused"), fuse_weight=0.5, fuse_top_k=7, device="cpu")
    ev = evaluate(ds, conf, models)
    entry = ev.results["methods"]["hvpr-fused"]["method"]
    assert entry["fused"] is True and entry["top_k"] == 7 and entry["fuse_weight"] == 0.5
    plain = ev.results["methods"]["hvpr"]["method"]
    assert plain["top_k"] == 20 and "fuse_weight" not in plain
    assert np.isfinite(ev.scores["hvpr-fused"][:, :7]).all() and np.isinf(ev.scores["hvpr-fused"][:, 7:]).all()


@pytest.fixture
def test_split_fused(synth_dataset):
    return synth_dataset.split("test")


def test_public_hvpr_checks_unit_rows_and_normalizes_like_knn_and_seqmatch(rng, caplog, monkeypatch):
    """seqnet.hvpr compared non-unit rows as given with neither the check nor normalize= of knn and seqmatch."""
    import logging

    import seqnet.core.log

    monkeypatch.setattr(seqnet.core.log, "_SAID", set())  # said once a process: another test may have said it
    unit = [x / np.linalg.norm(x, axis=1, keepdims=True) for x in
            (rng.standard_normal((12, 6)), rng.standard_normal((14, 6)), rng.standard_normal((14, 5)),
             rng.standard_normal((16, 5)))]
    scaled = [x * rng.uniform(0.3, 3, (len(x), 1)) for x in unit]
    starts = np.arange(12), np.arange(14)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        hvpr(*scaled, 3, *starts, top_k=5, device="cpu")
        hvpr(*scaled, 3, *starts, top_k=5, device="cpu")  # once a process, not once a call
    [line] = [r.getMessage() for r in caplog.records]
    assert line.startswith("hvpr: shortlist query row 0 has L2 norm") and "hvpr(..., normalize=True)" in line
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        got = hvpr(*scaled, 3, *starts, top_k=5, device="cpu", normalize=True)
        hvpr(*scaled, 3, *starts, top_k=5, device="cpu", normalize=False)
        want = hvpr(*unit, 3, *starts, top_k=5, device="cpu")
    assert not caplog.records
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_allclose(got[0], want[0], atol=1e-5)
    items, _ = naive_fused(*unit, 3, *starts, 5, 0.0)
    np.testing.assert_array_equal(want[1][:, :5], items)


def test_window_starts_of_the_wrong_length_name_themselves(rng):
    """24 q_starts for 27 shortlist rows were blamed on 'candidates', an argument hvpr has not got."""
    L = 4
    q, r = rng.standard_normal((30, 6)), rng.standard_normal((40, 6))
    sq, sr = rng.standard_normal((27, 5)), rng.standard_normal((37, 5))
    with pytest.raises(ConfigError, match=r"^q_starts must have one entry per shortlist_query row \(27\), got 24$"):
        hvpr(sq, sr, q, r, L, np.arange(24), np.arange(37), top_k=5, device="cpu")
    with pytest.raises(ConfigError, match=r"^r_starts must have one entry per shortlist_ref row \(37\), got 34$"):
        hvpr(sq, sr, q, r, L, list(range(27)), torch.arange(34), top_k=5, device="cpu")
    with pytest.raises(ConfigError, match=r"q_starts must have one entry.*got shape \(27, 1\)"):
        hvpr(sq, sr, q, r, L, np.arange(27)[:, None], np.arange(37), top_k=5, device="cpu")
    scores, items = hvpr(sq, sr, q, r, L, list(range(27)), torch.arange(37), top_k=5, device="cpu")
    n_items, n_scores = naive_fused(sq, sr, q, r, L, np.arange(27), np.arange(37), 5, 0.0)
    np.testing.assert_array_equal(items[:, :5], n_items)
    np.testing.assert_allclose(scores[:, :5], n_scores * L, rtol=1e-9)  # fuse 0: the matcher score, not / L
