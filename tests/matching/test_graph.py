"""Graph matching, GRH and the online matcher (seqnet.matching.graph) against brute force over all paths."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.core.tensors import l2_normalize
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.matching.graph import (
    OnlineGraphMatcher,
    graph_pairs,
    graph_topk,
    grh_pairs,
    grh_topk,
    lsh_candidates,
    near_mask,
    path_costs,
    runmin,
)
from seqnet.matching.hvpr import hvpr
from seqnet.matching.registry import SEQUENCE_MATCHERS
from seqnet.sequence.windows import window_starts

PIVOT = {"start": lambda L: 0, "centre": lambda L: L // 2, "end": lambda L: L - 1}


def all_paths(n_ref, L, fan_out):
    for j0 in range(n_ref):
        for steps in itertools.product(range(fan_out + 1), repeat=L - 1):
            path = [j0, *(j0 + np.cumsum(steps, dtype=int))]
            if path[-1] < n_ref:
                yield path


def brute_costs(q, r, L, fan_out, anchor="centre", allowed_starts=None):
    """``[Nq − L + 1, Nr]``: cheapest path through frame j at the pivot step, by enumeration."""
    p = PIVOT[anchor](L)
    out = np.full((len(q) - L + 1, len(r)), math.inf)
    for a in range(len(q) - L + 1):
        for path in all_paths(len(r), L, fan_out):
            if allowed_starts is None or path[0] in allowed_starts[a]:
                cost = sum(float(np.linalg.norm(q[a + t] - r[j])) for t, j in enumerate(path))
                out[a, path[p]] = min(out[a, path[p]], cost)
    return out


def stable_smallest(scores, k):
    return sorted(range(len(scores)), key=lambda j: (scores[j], j))[:k]


@pytest.fixture
def qr(rng):
    return rng.standard_normal((9, 3)), rng.standard_normal((10, 3))


# ----------------------------------------------------------------------------- the dynamic program


@pytest.mark.parametrize("fan_out", [0, 1, 2, 4, 12])
@pytest.mark.parametrize("backward", [False, True])
def test_runmin(rng, fan_out, backward):
    x = torch.from_numpy(rng.standard_normal((3, 9)))
    out = runmin(x, fan_out, backward).numpy()
    xs = x.numpy()
    for j in range(9):
        js = [j + s if backward else j - s for s in range(fan_out + 1)]
        np.testing.assert_array_equal(out[:, j], xs[:, [i for i in js if 0 <= i < 9]].min(1))


@pytest.mark.parametrize("L", [1, 2, 3, 4])
@pytest.mark.parametrize("fan_out", [0, 1, 2, 3])
@pytest.mark.parametrize("anchor", ["start", "centre", "end"])
def test_path_costs_vs_brute_force(qr, L, fan_out, anchor):
    q, r = qr
    got = path_costs(q, r, L, fan_out, anchor, device="cpu")
    assert got.shape == (len(q) - L + 1, len(r))
    np.testing.assert_allclose(got, brute_costs(q, r, L, fan_out, anchor), rtol=1e-9, atol=1e-9)


def test_fan_out_zero_is_a_stopped_camera(qr):
    q, r = qr
    L = 4
    got = path_costs(q, r, L, 0, device="cpu")
    d = np.linalg.norm(q[:, None] - r[None], axis=-1)
    np.testing.assert_allclose(got, [d[a : a + L].sum(0) for a in range(len(q) - L + 1)], rtol=1e-9)


@pytest.mark.parametrize("block_bytes", [1, 400, None])
def test_blocks_and_topk(qr, rng, block_bytes):
    q, r = qr
    q = np.concatenate([q, q[::-1]])
    L, k = 3, 4
    p = L // 2
    full = brute_costs(q, r, L, 2)[:, p : p + len(r) - L + 1]
    np.testing.assert_allclose(path_costs(q, r, L, device="cpu", block_bytes=block_bytes)[:, p : p + len(r) - L + 1],
                               full, rtol=1e-9)
    q_starts, r_starts = rng.permutation(len(q) - L + 1)[:7], np.sort(rng.permutation(len(r) - L + 1)[:6])
    vals, items = graph_topk(q, r, L, k, q_starts, r_starts, device="cpu", block_bytes=block_bytes)
    for m, a in enumerate(q_starts):
        row = full[a, r_starts]
        assert items[m].tolist() == stable_smallest(row.tolist(), k)
        np.testing.assert_allclose(vals[m], row[items[m]], rtol=1e-9)


def test_topk_ties_lower_item_wins(rng):
    x = rng.integers(-3, 4, (8, 3)).astype(np.float64)
    vals, items = graph_topk(x, np.concatenate([x, x]), 3, 2, np.array([0, 3]), np.arange(14), device="cpu")
    assert items.tolist() == [[0, 8], [3, 11]]
    np.testing.assert_allclose(vals, 0.0, atol=1e-12)


@pytest.mark.parametrize("L", [1, 3, 4])
@pytest.mark.parametrize("fan_out", [0, 2])
@pytest.mark.parametrize("anchor", ["start", "centre", "end"])
def test_pairs_equal_the_map(qr, rng, L, fan_out, anchor):
    q, r = qr
    p = PIVOT[anchor](L)
    items = brute_costs(q, r, L, fan_out, anchor)[:, p : p + len(r) - L + 1]
    q_starts = rng.integers(0, len(q) - L + 1, 6)
    cand = rng.integers(-1, len(r) - L + 1, (6, 4))
    got = graph_pairs(torch.from_numpy(q), torch.from_numpy(r), L, torch.from_numpy(q_starts),
                      torch.from_numpy(cand), fan_out, anchor, block_bytes=500).numpy()
    expected = np.where(cand < 0, np.inf, items[q_starts[:, None], cand.clip(0)])
    np.testing.assert_allclose(got, expected, rtol=1e-9)


def test_bad_parameters(qr):
    q, r = qr
    for kwargs, pattern in (({"fan_out": -1}, "fan_out"), ({"anchor": "middle"}, "anchor"),
                            ({"fan_out": 1.5}, "fan_out")):
        with pytest.raises(ConfigError, match=pattern):
            graph_topk(q, r, 3, 2, np.arange(3), np.arange(3), device="cpu", **kwargs)
    with pytest.raises(ConfigError, match="seq_len"):
        path_costs(q, r, 0, device="cpu")
    with pytest.raises(ConfigError, match="seq_len"):
        graph_topk(q, r, 11, 2, np.arange(1), np.arange(1), device="cpu")
    for kwargs, pattern in (({"nbits": 0}, "nbits"), ({"candidates": 0}, "candidates"),
                            ({"neighbourhood": -1}, "neighbourhood")):
        with pytest.raises(ConfigError, match=pattern):
            grh_topk(q, r, 3, 2, np.arange(3), np.arange(3), device="cpu", **kwargs)
    with pytest.raises(ConfigError, match="candidate window starts"):
        graph_pairs(torch.from_numpy(q), torch.from_numpy(r), 3, torch.tensor([0]), torch.tensor([[8]]))


# ----------------------------------------------------------------------------- variable speed


@pytest.mark.parametrize("speed", ["half", "double"])
def test_variable_speed_toy(rng, speed):
    """Half speed (frames repeated) and double speed (frames dropped): the variable-speed matchers find
    the exact item, fixed-speed SeqMatch mostly does not."""
    r = rng.standard_normal((80, 8))
    idx = np.repeat(np.arange(20, 45), 2) if speed == "half" else np.arange(5, 75, 2)
    q = r[idx] + 0.05 * rng.standard_normal((len(idx), 8))
    L = 7
    q_starts, r_starts = np.arange(len(q) - L + 1), np.arange(len(r) - L + 1)
    true = idx[q_starts + L // 2] - L // 2  # the item whose centre frame is the query centre frame's place
    hits = {m: (SEQUENCE_MATCHERS[m].topk(q, r, L, 1, q_starts, r_starts, device="cpu")[1][:, 0] == true).mean()
            for m in ("seqmatch", "vseqmatch", "graph", "grh")}
    assert hits["vseqmatch"] == hits["graph"] == hits["grh"] == 1.0, hits
    assert hits["seqmatch"] < 0.5, hits


# ----------------------------------------------------------------------------- GRH


def test_lsh_candidates_deterministic_and_hamming(rng):
    import faiss

    q, r = rng.standard_normal((12, 6)).astype(np.float32), rng.standard_normal((30, 6)).astype(np.float32)
    a = lsh_candidates(q, r, 32, 5, device="cpu")
    np.testing.assert_array_equal(a, lsh_candidates(q, r, 32, 5, device="cpu", block_bytes=1))
    assert a.shape == (12, 5) and a.dtype == np.int64
    assert lsh_candidates(q, r, 32, 100, device="cpu").shape == (12, 30)
    index = faiss.IndexLSH(6, 32, True, True)
    index.train(r)
    index.add(r)
    dist, _ = index.search(q, 5)
    codes_q, codes_r = (np.unpackbits(index.sa_encode(x), axis=1) for x in (q, r))
    ham = (codes_q[:, None] != codes_r[None]).sum(-1)
    np.testing.assert_array_equal(np.take_along_axis(ham, a, 1), dist)  # the faiss distances, smallest first
    for m in range(12):
        assert a[m].tolist() == stable_smallest(ham[m].tolist(), 5)


def test_near_mask():
    cands = torch.tensor([[0, 7], [-1, -1], [4, -1]])
    got = near_mask(cands, 9, 1).numpy()
    expected = np.array([[abs(j - c) <= 1 for j in range(9)] for c in (0, 7)]).any(0)
    np.testing.assert_array_equal(got, [expected, np.zeros(9, bool), [3 <= j <= 5 for j in range(9)]])


@pytest.mark.parametrize("anchor", ["start", "centre"])
def test_grh_restricts_path_starts(qr, anchor):
    q, r = qr
    L, nb, radius = 3, len(r) - 2, 1
    cands = lsh_candidates(q, r, 16, 2, device="cpu")
    allowed = [{j for c in cands[a] for j in range(c - radius, c + radius + 1)} for a in range(len(q))]
    p = PIVOT[anchor](L)
    full = brute_costs(q, r, L, 2, anchor, allowed)[:, p : p + nb]
    vals, items = grh_topk(q, r, L, nb, np.arange(len(q) - 2), np.arange(nb), nbits=16, candidates=2,
                           neighbourhood=radius, anchor=anchor, device="cpu")
    np.testing.assert_allclose(vals, np.take_along_axis(full, items, 1), rtol=1e-9)
    assert np.isinf(vals).any() and np.isfinite(vals[:, 0]).all()
    got = grh_pairs(torch.from_numpy(q), torch.from_numpy(r), L, torch.arange(len(q) - 2), torch.from_numpy(items),
                    nbits=16, candidates=2, neighbourhood=radius, anchor=anchor)
    np.testing.assert_allclose(got.numpy(), vals, rtol=1e-9)


def test_grh_with_enough_candidates_is_graph(qr, rng):
    q, r = qr
    qs, rs = np.arange(7), np.arange(8)
    expected = graph_topk(q, r, 3, 5, qs, rs, device="cpu")
    for kwargs in ({"candidates": len(r)}, {"candidates": 1, "neighbourhood": len(r)}):
        got = grh_topk(q, r, 3, 5, qs, rs, nbits=8, device="cpu", **kwargs)
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])
    cand = torch.from_numpy(rng.integers(-1, 8, (7, 3)))
    np.testing.assert_array_equal(grh_pairs(*map(torch.from_numpy, (q, r)), 3, torch.from_numpy(qs), cand,
                                            candidates=len(r)),
                                  graph_pairs(*map(torch.from_numpy, (q, r)), 3, torch.from_numpy(qs), cand))
    again = grh_topk(q, r, 3, 5, qs, rs, nbits=8, candidates=2, device="cpu")
    np.testing.assert_array_equal(again[1], grh_topk(q, r, 3, 5, qs, rs, nbits=8, candidates=2, device="cpu")[1])


# ----------------------------------------------------------------------------- online


def test_online_equals_offline_causal_dp(rng):
    q, r = rng.standard_normal((8, 4)), rng.standard_normal((12, 4))
    online = OnlineGraphMatcher(r, fan_out=2, device="cpu")
    for t in range(len(q)):
        j, cost = online.step(q[t])
        offline = path_costs(q[: t + 1], r, t + 1, 2, "end", device="cpu")[0]  # paths over frames 0..t, ending now
        assert j == int(np.argmin(offline)) and cost == pytest.approx(offline.min(), rel=1e-9)
        if t >= 2:  # graph <= seqmatch: the fixed-speed window is one of the paths
            fixed = np.linalg.norm(q[: t + 1] - r[j - t : j + 1], axis=1).sum() if j >= t else math.inf
            assert cost <= fixed + 1e-9
    online.reset()
    assert online.step(q[3])[0] == int(np.argmin(np.linalg.norm(r - q[3], axis=1)))


def brute_online(q, r, fan_out, lam):
    """Cheapest match-or-no-match path over all frames: ``(end frame or -1, cost)``, by enumeration."""
    best = (math.inf, None)
    for path in all_paths(len(r), len(q), fan_out):
        for flags in itertools.product((False, True), repeat=len(q)):
            nodes = enumerate(zip(path, flags, strict=True))
            cost = sum(lam if f else float(np.linalg.norm(q[t] - r[j])) for t, (j, f) in nodes)
            best = min(best, (cost, -1 if flags[-1] else path[-1]), key=lambda x: x[0])
    return best[1], best[0]


def test_online_no_match_nodes_vs_brute_force(rng):
    r = rng.standard_normal((6, 2))
    q = np.concatenate([r[[1, 2]], 5 + rng.standard_normal((1, 2)), r[[3]]]) + 0.3 * rng.standard_normal((4, 2))
    online = OnlineGraphMatcher(r, fan_out=1, no_match_cost=1.5, relocalise_after=100)
    for t in range(len(q)):
        j, cost = online.step(q[t])
        bj, bcost = brute_online(q[: t + 1], r, 1, 1.5)
        assert (j, cost) == (bj, pytest.approx(bcost, rel=1e-9)), t


def test_online_recovers_after_garbage(rng):
    r = rng.standard_normal((80, 8)).astype(np.float32)
    truth = np.concatenate([np.arange(0, 20), -np.ones(6, int), np.arange(50, 70)])  # a jump after the garbage
    q = np.where(truth[:, None] >= 0, r[truth.clip(0)], 3 * rng.standard_normal((len(truth), 8)))
    q = q + 0.05 * rng.standard_normal(q.shape)
    online = OnlineGraphMatcher(r, fan_out=2, no_match_cost=2.0, relocalise_after=3)
    got, lengths = zip(*[(online.step(x)[0], online.length) for x in q], strict=True)
    got = np.array(got)
    assert lengths[:23] == tuple(range(1, 24)) and lengths[23] == 1  # frames 20-22 no match: frame 23 restarts
    np.testing.assert_array_equal(got[:20], truth[:20])
    assert (got[20:26] == -1).all()  # no match while the frames are garbage
    np.testing.assert_array_equal(got[26:], truth[26:])  # relocalised at the first good frame
    stubborn = OnlineGraphMatcher(r, fan_out=2, no_match_cost=2.0, relocalise_after=1000)  # never restarts
    assert (np.array([stubborn.step(x)[0] for x in q])[26:32] != truth[26:32]).all()  # 50 is out of reach
    with pytest.raises(ConfigError, match="D=8"):
        online.step(np.zeros(3))
    with pytest.raises(ConfigError, match="no_match_cost"):
        OnlineGraphMatcher(r, no_match_cost=-1.0)
    with pytest.raises(ConfigError, match="fan_out"):
        OnlineGraphMatcher(r, fan_out=-1)


# ----------------------------------------------------------------------------- evaluation and HVPR


def test_hvpr_reranks_with_graph(rng):
    q, r = rng.standard_normal((12, 3)), rng.standard_normal((14, 3))
    qs, rs = np.arange(10), np.arange(12)
    sq, sr = rng.standard_normal((10, 5)), rng.standard_normal((12, 5))
    scores, items = hvpr(sq, sr, q, r, 3, qs, rs, top_k=4, matcher="graph", device="cpu")
    full = brute_costs(q, r, 3, 2)[:, 1:13]
    np.testing.assert_allclose(scores, np.take_along_axis(full, items, 1), rtol=1e-9)
    assert (np.diff(scores, axis=1) >= 0).all()


def test_evaluate_with_new_matchers():
    ds = make_synthetic(places=200, dim=16, seed=1).split("test")
    methods = ("raw+seqmatch", "raw+vseqmatch", "raw+graph", "hvpr-delta:raw+graph")
    ev = evaluate(ds, EvalConfig(methods=methods, seq_len=5, device="cpu"))
    res = ev.results["methods"]
    assert list(res) == list(methods)
    assert all(0 <= res[m]["recall@1"] <= res[m]["recall@5"] <= 1 for m in methods)
    assert res["raw+graph"]["method"]["rerank"] == "raw+graph"
    raw_q, raw_r = (l2_normalize(torch.from_numpy(np.asarray(t.descriptors))).double().numpy()
                    for t in (ds.query, ds.reference))
    qs, rs = window_starts(len(ds.query), 5)[0][ev.q_items], window_starts(len(ds.reference), 5)[0][ev.r_items]
    full = path_costs(raw_q, raw_r, 5, device="cpu")[:, 2:]  # item b <-> frame b + 2 (centre anchor)
    for name, n in (("raw+graph", 100), ("hvpr-delta:raw+graph", 20)):
        got = ev.retrieved[name][:, :n]
        scores = full[qs[:, None], rs[got]]
        if name == "raw+graph":  # the best items, up to float32 near-ties
            np.testing.assert_allclose(scores, np.sort(full[qs][:, rs], axis=1)[:, :n], atol=1e-4)
        assert (np.diff(scores, axis=1) >= -1e-4).all()


def test_grh_on_wide_descriptors_says_once_what_it_costs(rng, caplog):
    from seqnet.matching.graph import WIDE_LSH, lsh_candidates

    r = rng.standard_normal((30, WIDE_LSH + 1)).astype(np.float32)
    with caplog.at_level("WARNING", logger="seqnet"):
        lsh_candidates(r[:2], r, 16, 3)
        lsh_candidates(r[:2], r, 16, 3)
    assert [m for m in caplog.messages if "dominate the cost" in m] == [caplog.messages[0]]
    caplog.clear()
    lsh_candidates(r[:2, :64], r[:, :64], 16, 3)
    assert not caplog.messages
