"""Learned binary codes for GRH (grh-dh): Hamming search, the hashing network's training, the matcher end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.matching.graph import graph_topk, grh_pairs, grh_topk
from seqnet.matching.hashing import (
    HashSettings,
    dh_candidates,
    hamming_topk,
    hash_loss,
    sample_pairs,
    train_hash,
)
from seqnet.matching.registry import SEQUENCE_MATCHERS

FAST = HashSettings(steps=30, batch=32, pos_frames=1, neg_frames=3)


def naive_hamming_topk(qb, rb, c):
    """Nearest codes by an explicit popcount of XOR, ties by the lower frame."""
    out = []
    for x in qb:
        ham = [int(np.count_nonzero(np.logical_xor(x, y))) for y in rb]
        out.append(sorted(range(len(rb)), key=lambda j: (ham[j], j))[:c])
    return np.array(out)


@pytest.mark.parametrize("block_bytes", [None, 1])
def test_hamming_topk_equals_a_loop_ties_included(rng, block_bytes):
    qb, rb = (rng.integers(0, 2, (n, 3)).astype(bool) for n in (7, 25))  # 3 bits, 25 frames: many ties
    rb[10] = rb[3]  # an exact duplicate code
    for c in (1, 4, 25, 40):
        got = hamming_topk(torch.from_numpy(qb).float(), torch.from_numpy(rb).float(), c, block_bytes)
        np.testing.assert_array_equal(got, naive_hamming_topk(qb, rb, c))
    with pytest.raises(ConfigError, match="candidates"):
        hamming_topk(torch.zeros(1, 3), torch.zeros(2, 3), 0)


def test_sample_pairs_are_near_and_far(rng):
    gen = torch.Generator().manual_seed(0)
    a, p, c = sample_pairs(50, 500, 2, 10, gen)
    assert ((a - p).abs() <= 2).all() and (a != p).all() and ((a - c).abs() > 10).all()
    assert ((p >= 0) & (p < 50) & (c >= 0) & (c < 50)).all()
    a, p, c = sample_pairs(3, 50, 2, 10, gen)  # too short for the far negatives: still other frames
    assert (a != c).all() and ((p >= 0) & (p < 3)).all()


def walk(rng, n=120, dim=16):
    """Ordered frames of a random walk (neighbours in the order are near in descriptor space)."""
    return np.cumsum(rng.standard_normal((n, dim)), 0).astype(np.float32)


def test_training_decreases_the_loss_and_is_deterministic(rng):
    x = walk(rng)
    settings = HashSettings(steps=80, batch=64)
    first, again = train_hash(x, 32, settings), train_hash(x, 32, settings)
    np.testing.assert_array_equal(first.losses, again.losses)
    assert torch.equal(first.net.linear.weight, again.net.linear.weight)
    assert first.losses[-10:].mean() < 0.8 * first.losses[:10].mean()
    untrained = train_hash(x, 32, HashSettings(steps=1, lr=0.0, batch=64))  # the seeded init, not trained
    gen = torch.Generator().manual_seed(1)
    a, p, c = sample_pairs(len(x), 2000, settings.pos_frames, settings.neg_frames, gen)  # held-out pairs
    xt = torch.from_numpy(x)
    with torch.no_grad():
        before, after = (float(hash_loss(n(xt[a]), n(xt[p]), n(xt[c]), settings.margin, settings.quant))
                         for n in (untrained.net, first.net))
    assert after < 0.8 * before
    other = train_hash(x, 32, HashSettings(steps=80, batch=64, seed=1))
    assert not torch.equal(first.net.linear.weight, other.net.linear.weight)


def test_dh_candidates_are_the_nets_codes_searched(rng):
    r = walk(rng, 40, 8)
    q = r[::3] + 0.05 * rng.standard_normal((14, 8)).astype(np.float32)
    net = train_hash(r, 6, FAST).net
    with torch.no_grad():  # the codes by hand: the sign of W (x - mean) / scale + b
        w, b = net.linear.weight.numpy(), net.linear.bias.numpy()
        qb, rb = (((x - net.mean.numpy()) / float(net.scale)) @ w.T + b >= 0 for x in (q, r))
    got = dh_candidates(q, r, 6, 5, device="cpu", settings=FAST)
    np.testing.assert_array_equal(got, naive_hamming_topk(qb, rb, 5))
    np.testing.assert_array_equal(got, dh_candidates(q, r, 6, 5, device="cpu", block_bytes=1, settings=FAST))


def brute_grh(q, r, L, fan_out, pivot, cands, radius):
    """``[Nq − L + 1, Nr]``: cheapest path through frame j at the pivot step that starts within ``radius`` of a
    candidate of the window's first frame, by enumerating every path."""
    out = np.full((len(q) - L + 1, len(r)), math.inf)
    for a in range(len(q) - L + 1):
        for j0 in range(len(r)):
            if min(abs(j0 - c) for c in cands[a]) > radius:
                continue
            for steps in np.ndindex(*(fan_out + 1,) * (L - 1)):
                path = [j0, *(j0 + np.cumsum(steps, dtype=int))]
                if path[-1] < len(r):
                    cost = sum(float(np.linalg.norm(q[a + t] - r[j])) for t, j in enumerate(path))
                    out[a, path[pivot]] = min(out[a, path[pivot]], cost)
    return out


@pytest.mark.parametrize("anchor,pivot", [("start", 0), ("centre", 1)])
def test_grh_dh_path_scores_equal_a_loop(rng, anchor, pivot):
    q, r = rng.standard_normal((9, 3)), rng.standard_normal((10, 3))
    L, nb, radius = 3, len(r) - 2, 1
    cands = dh_candidates(q, r, 8, 2, device="cpu")  # the matcher's own defaults (HashSettings())
    full = brute_grh(q, r, L, 2, pivot, cands, radius)[:, pivot : pivot + nb]
    vals, items = grh_topk(q, r, L, nb, np.arange(len(q) - 2), np.arange(nb), nbits=8, candidates=2,
                           neighbourhood=radius, anchor=anchor, device="cpu", codes="dh")
    np.testing.assert_allclose(vals, np.take_along_axis(full, items, 1), rtol=1e-9)
    assert np.isinf(vals).any() and np.isfinite(vals[:, 0]).all()
    got = grh_pairs(torch.from_numpy(q), torch.from_numpy(r), L, torch.arange(len(q) - 2), torch.from_numpy(items),
                    nbits=8, candidates=2, neighbourhood=radius, anchor=anchor, codes="dh")
    np.testing.assert_allclose(got.numpy(), vals, rtol=1e-9)


def test_registry_and_bad_codes(rng):
    spec = SEQUENCE_MATCHERS["grh-dh"]
    assert spec.anchored and not spec.online  # offline only, like grh
    q = rng.standard_normal((6, 3))
    with pytest.raises(ConfigError, match="unknown GRH codes 'pq'; valid: lsh, dh"):
        grh_topk(q, q, 3, 2, np.arange(4), np.arange(4), codes="pq", device="cpu")
    with pytest.raises(ConfigError, match="steps"):
        HashSettings(steps=0)


def test_grh_dh_with_every_frame_a_candidate_is_graph(rng):
    q, r = rng.standard_normal((9, 3)), rng.standard_normal((10, 3))
    qs, rs = np.arange(7), np.arange(8)
    expected = graph_topk(q, r, 3, 5, qs, rs, device="cpu")
    got = grh_topk(q, r, 3, 5, qs, rs, nbits=8, candidates=len(r), device="cpu", codes="dh")
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])


def test_grh_dh_through_seqnet_eval(synth_dir, map_models, tmp_path):
    from seqnet.cli import main as cli

    methods = ["raw+grh-dh", "s1+grh-dh", "hvpr-delta:raw+grh-dh", "raw+graph"]
    runs = []
    for out in ("a", "b"):
        args = ["eval", "--dataset", str(synth_dir), "--model", str(map_models[1]), "--seq-len", "5",
                "--out", str(tmp_path / out), *(a for m in methods for a in ("--method", m))]
        assert cli(args) == 0
        runs.append(json.loads((tmp_path / out / "results.json").read_text())["methods"])
    res = runs[0]
    assert list(res) == methods
    for m in methods:
        assert 0 <= res[m]["recall@1"] <= res[m]["recall@5"] <= 1 and res[m]["queries"] == res["raw+graph"]["queries"]
        assert all(runs[1][m][k] == v for k, v in res[m].items() if k.startswith("recall@"))  # deterministic
    assert res["s1+grh-dh"]["method"]["rerank"] == "s1+grh-dh"
