"""Velocity-robust SeqMatch (seqnet.matching.velocity) against a naive triple loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.matching.hvpr import hvpr
from seqnet.matching.pairs import window_scores
from seqnet.matching.registry import SEQUENCE_MATCHERS
from seqnet.matching.seqmatch import seqmatch, seqmatch_topk
from seqnet.matching.velocity import (
    DEFAULT_VELOCITIES,
    check_velocities,
    pivot_step,
    trajectories,
    velocity_map,
    velocity_pairs,
    velocity_topk,
)

ANCHOR_STEP = {"start": lambda L: 0, "centre": lambda L: L // 2, "end": lambda L: L - 1}


def rnd(x):
    """Round half away from zero, written independently of the module."""
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


def naive_traj(b, L, v, anchor, reverse):
    p = ANCHOR_STEP[anchor](L)
    return [b + L - 1 - p - rnd(v * (t - p)) if reverse else b + p + rnd(v * (t - p)) for t in range(L)]


def naive_pair(q, r, a, b, L, vels, anchor="centre", reverse=False):
    best = math.inf
    for v in vels:
        frames = naive_traj(b, L, v, anchor, reverse)
        if min(frames) >= 0 and max(frames) < len(r):
            best = min(best, sum(float(np.linalg.norm(q[a + t] - r[f])) for t, f in enumerate(frames)))
    return best


def naive_map(q, r, L, vels, anchor="centre", reverse=False):
    return np.array([[naive_pair(q, r, a, b, L, vels, anchor, reverse) for b in range(len(r) - L + 1)]
                     for a in range(len(q) - L + 1)]).reshape(len(q) - L + 1, len(r) - L + 1)


def stable_smallest(scores, k):
    return sorted(range(len(scores)), key=lambda j: (scores[j], j))[:k]


@pytest.fixture
def qr(rng):
    return rng.standard_normal((15, 4)), rng.standard_normal((13, 4))


VELOCITY_SETS = [DEFAULT_VELOCITIES, (1.0,), (0.5,), (2.0, 3.0), (0.3, 1.7, 1.0)]


# ----------------------------------------------------------------------------- definitions


def test_trajectories_documented_examples():
    assert trajectories((0.5,), 5, "start") == [(0, 1, 1, 2, 2)]
    assert trajectories((0.5,), 5, "centre") == [(1, 1, 2, 3, 3)]  # symmetric about the pivot frame b + 2
    assert trajectories((2.0,), 5, "centre") == [(-2, 0, 2, 4, 6)]
    assert trajectories((2.0,), 5, "end") == [(-4, -2, 0, 2, 4)]
    assert trajectories((1.0,), 4, "centre", reverse=True) == [(3, 2, 1, 0)]  # = seqmatch-rev
    assert trajectories((1.5,), 3, "start", reverse=True) == [(2, 0, -1)]
    assert trajectories(DEFAULT_VELOCITIES, 1) == [(0,)]  # L = 1: one frame, every slope the same
    assert trajectories((0.75, 1.0), 2, "start") == [(0, 1)]  # identical trajectories are scored once
    assert [pivot_step(a, 5) for a in ("start", "centre", "end")] == [0, 2, 4]


@pytest.mark.parametrize("bad", [(), [0.0], [1.0, -0.5], [math.nan], [math.inf], "1.0", 2.0, None, ["fast"]])
def test_bad_velocities(bad):
    with pytest.raises(ConfigError, match="velocit"):
        check_velocities(bad)


def test_bad_parameters(qr):
    q, r = qr
    with pytest.raises(ConfigError, match="anchor"):
        velocity_topk(q, r, 3, 2, np.arange(3), np.arange(3), anchor="middle", device="cpu")
    with pytest.raises(ConfigError, match="seq_len"):
        velocity_topk(q, r, 0, 2, np.arange(3), np.arange(3), device="cpu")
    with pytest.raises(ConfigError, match="seq_len"):
        velocity_map(q, r, 14, device="cpu")
    with pytest.raises(ConfigError, match="k must be"):
        velocity_topk(q, r, 3, 0, np.arange(3), np.arange(3), device="cpu")
    with pytest.raises(ConfigError, match="velocities"):
        velocity_topk(q, r, 3, 2, np.arange(3), np.arange(3), velocities=[], device="cpu")
    with pytest.raises(ConfigError, match="reference window starts"):
        velocity_topk(q, r, 3, 2, np.arange(3), np.array([11]), device="cpu")


# ----------------------------------------------------------------------------- whole map


@pytest.mark.parametrize("L", [1, 2, 3, 5])
@pytest.mark.parametrize("vels", VELOCITY_SETS, ids=str)
@pytest.mark.parametrize("anchor", ["start", "centre", "end"])
@pytest.mark.parametrize("reverse", [False, True])
def test_map_vs_triple_loop(qr, L, vels, anchor, reverse):
    q, r = qr
    m = velocity_map(q, r, L, vels, reverse, anchor, device="cpu")
    assert m.shape == (len(q) - L + 1, len(r) - L + 1) and m.dtype == np.float64
    np.testing.assert_allclose(m, naive_map(q, r, L, vels, anchor, reverse), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("L", [1, 3, 4])
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("anchor", ["start", "centre"])
def test_unit_velocity_is_fixed_speed_seqmatch_exactly(qr, rng, L, reverse, anchor):
    q, r = qr
    np.testing.assert_array_equal(velocity_map(q, r, L, (1,), reverse, anchor, device="cpu"),
                                  seqmatch(q, r, L, reverse=reverse, device="cpu"))
    qs, rs = rng.permutation(len(q) - L + 1)[:6], np.arange(len(r) - L + 1)
    a = velocity_topk(q, r, L, 4, qs, rs, velocities=(1.0,), reverse=reverse, anchor=anchor, device="cpu")
    b = seqmatch_topk(q, r, L, 4, qs, rs, reverse=reverse, device="cpu")
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    qt, rt = torch.from_numpy(q), torch.from_numpy(r)
    cand = torch.from_numpy(rng.integers(-1, len(r) - L + 1, (len(qs), 5)))
    np.testing.assert_array_equal(velocity_pairs(qt, rt, L, torch.from_numpy(qs), cand, (1.0,), reverse, anchor),
                                  window_scores(qt, rt, L, torch.from_numpy(qs), cand, reverse, strategy="gather"))


def test_windows_near_the_end(qr):
    """Fast trajectories that leave the traverse are inf; slope 1 keeps every item finite."""
    q, r = qr
    L = 4
    m = velocity_map(q, r, L, (2.0,), anchor="start", device="cpu")
    nb = len(r) - L + 1
    assert np.isfinite(m[:, : nb - 3]).all() and np.isinf(m[:, nb - 3 :]).all()  # b + 6 must be <= 12
    assert np.isfinite(velocity_map(q, r, L, DEFAULT_VELOCITIES, device="cpu")).all()
    m = velocity_map(q, r, L, (2.0,), anchor="centre", device="cpu")  # offsets -2, 0, 2, 4
    assert np.isinf(m[:, :2]).all() and np.isinf(m[:, nb - 1 :]).all() and np.isfinite(m[:, 2 : nb - 1]).all()


@pytest.mark.parametrize("block_bytes", [1, 300, 5000, None])
@pytest.mark.parametrize("L", [1, 3])
def test_blocks(qr, block_bytes, L):
    q, r = qr
    q = np.concatenate([q, q[::-1]])
    m = velocity_map(q, r, L, block_bytes=block_bytes, device="cpu")
    np.testing.assert_allclose(m, naive_map(q, r, L, DEFAULT_VELOCITIES), rtol=1e-9, atol=1e-9)
    vals, _ = velocity_topk(q, r, L, 3, np.arange(len(q) - L + 1), np.arange(len(r) - L + 1), device="cpu",
                            block_bytes=block_bytes)
    np.testing.assert_allclose(vals, np.sort(m, axis=1)[:, :3], rtol=1e-9, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(nq=st.integers(1, 10), nr=st.integers(1, 10), L=st.integers(1, 4), reverse=st.booleans(),
       anchor=st.sampled_from(["start", "centre", "end"]), block_bytes=st.sampled_from([None, 1, 200]),
       vels=st.lists(st.sampled_from([0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 3.0]), min_size=1, max_size=4),
       seed=st.integers(0, 2**16))
def test_map_property(nq, nr, L, reverse, anchor, block_bytes, vels, seed):
    rng = np.random.default_rng(seed)
    q, r = rng.standard_normal((nq, 3)), rng.standard_normal((nr, 3))
    if L > min(nq, nr):
        with pytest.raises(ConfigError):
            velocity_map(q, r, L, vels, device="cpu")
        return
    m = velocity_map(q, r, L, vels, reverse, anchor, device="cpu", block_bytes=block_bytes)
    np.testing.assert_allclose(m, naive_map(q, r, L, vels, anchor, reverse), rtol=1e-9, atol=1e-9)


def test_float32_inputs(qr):
    q, r = (x.astype(np.float32) for x in qr)
    m = velocity_map(q, r, 3, device="cpu")
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, naive_map(q.astype(float), r.astype(float), 3, DEFAULT_VELOCITIES), rtol=1e-4)


# ----------------------------------------------------------------------------- top-k and pairs


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("block_bytes", [None, 100])
def test_topk_vs_loop(qr, rng, reverse, block_bytes):
    q, r = qr
    L = 3
    q_starts = rng.permutation(len(q) - L + 1)[:8]
    r_starts = np.sort(rng.permutation(len(r) - L + 1)[:9])
    vals, items = velocity_topk(q, r, L, 4, q_starts, r_starts, reverse=reverse, device="cpu",
                                block_bytes=block_bytes)
    full = naive_map(q, r, L, DEFAULT_VELOCITIES, reverse=reverse)
    for m, a in enumerate(q_starts):
        row = full[a, r_starts]
        assert items[m].tolist() == stable_smallest(row.tolist(), 4)
        np.testing.assert_allclose(vals[m], row[items[m]], rtol=1e-9)


def test_topk_ties_lower_item_wins(rng):
    x = rng.integers(-3, 4, (8, 3)).astype(np.float64)
    vals, items = velocity_topk(x, np.concatenate([x, x]), 2, 2, np.array([0, 3]), np.arange(15), device="cpu")
    assert items.tolist() == [[0, 8], [3, 11]]
    np.testing.assert_allclose(vals, 0.0, atol=1e-12)


@pytest.mark.parametrize("vels", VELOCITY_SETS, ids=str)
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("L", [1, 4])
def test_pairs_vs_loop(qr, rng, vels, reverse, L):
    q, r = qr
    na, nb = len(q) - L + 1, len(r) - L + 1
    q_starts = rng.integers(0, na, 7)
    cand = rng.integers(-1, nb, (7, 5))
    cand[0] = -1
    s = velocity_pairs(torch.from_numpy(q), torch.from_numpy(r), L, torch.from_numpy(q_starts),
                       torch.from_numpy(cand), vels, reverse, block_bytes=300)
    assert s.shape == (7, 5)
    for m, a in enumerate(q_starts):
        for j, b in enumerate(cand[m]):
            expected = math.inf if b < 0 else naive_pair(q, r, a, b, L, vels, reverse=reverse)
            assert s[m, j].item() == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_pairs_errors(qr):
    q, r = (torch.from_numpy(x) for x in qr)
    with pytest.raises(ConfigError, match="candidate window starts"):
        velocity_pairs(q, r, 3, torch.tensor([0]), torch.tensor([[11]]))
    with pytest.raises(ConfigError, match="query window starts"):
        velocity_pairs(q, r, 3, torch.tensor([13]), torch.tensor([[0]]))
    with pytest.raises(ConfigError, match=r"\[M\]"):
        velocity_pairs(q, r, 3, torch.tensor([0, 1]), torch.tensor([[0]]))
    assert velocity_pairs(q, r, 3, torch.tensor([0]), torch.zeros((1, 0), dtype=torch.long)).shape == (1, 0)


# ----------------------------------------------------------------------------- registry and HVPR


def test_registered_matchers(qr, rng):
    q, r = qr
    qs, rs = np.arange(10), np.arange(9)
    for name, reverse in (("vseqmatch", False), ("vseqmatch-rev", True)):
        got = SEQUENCE_MATCHERS[name].topk(q, r, 5, 3, qs, rs, device="cpu")
        np.testing.assert_array_equal(got[1], velocity_topk(q, r, 5, 3, qs, rs, reverse=reverse, device="cpu")[1])
    sq, sr = rng.standard_normal((10, 6)), rng.standard_normal((9, 6))
    scores, items = hvpr(sq, sr, q, r, 5, qs, rs, top_k=4, matcher="vseqmatch", device="cpu")
    for m in range(10):
        expected = [naive_pair(q, r, qs[m], rs[j], 5, DEFAULT_VELOCITIES) for j in items[m]]
        np.testing.assert_allclose(scores[m], expected, rtol=1e-9)
        assert list(scores[m]) == sorted(scores[m])
