"""TraverseReference: the dataset side of the one Reference, against the array functions it wraps."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.data.synth import make_synthetic
from seqnet.matching.hvpr import pair_scores
from seqnet.matching.seqmatch import seqmatch_topk
from seqnet.methods.grammar import parse_method
from seqnet.reference import TraverseReference
from seqnet.search.knn import knn
from seqnet.sequence.windows import Windows


def _ref(mode="centred"):
    ds = make_synthetic(places=100, dim=8, seed=2)
    return ds, TraverseReference(ds.reference, Windows(3, 4, mode), {}, torch.device("cpu"))


def test_items_and_search_equal_knn_over_the_described_items(rng):
    ds, ref = _ref()
    assert ref.items.tolist() == ref.described.side.items.tolist() and len(ref.items) > 0
    assert ref.prepare(parse_method("delta")) >= 0.0
    q = rng.standard_normal((7, 8)).astype(np.float32)
    got = ref.search("delta", q, 5)
    want = knn(q, ref.described.items("delta"), 5)
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_allclose(got[0], want[0], rtol=1e-6)
    np.testing.assert_array_equal(ref.search("delta", q, 5)[1], want[1])  # the kept index answers alike


def test_rerank_and_match_equal_the_matcher_functions(rng):
    ds, ref = _ref("causal")
    frames = ref.described.frames("single")
    q = torch.as_tensor(rng.standard_normal((20, 8)).astype(np.float32))
    q_starts = np.array([0, 5, 16])
    cand = np.array([[0, 3, -1], [10, 2, 7], [1, 1, 4]])
    got = ref.rerank("single", "seqmatch", q, q_starts, cand)
    want = pair_scores(q, frames, 4, q_starts, ref.match_starts, cand)
    np.testing.assert_allclose(got.numpy(), want.numpy())
    assert np.isinf(float(got[0, 2]))
    scores, items = ref.match("single", "seqmatch", q, q_starts, 6)
    w_scores, w_items = seqmatch_topk(q, frames, 4, 6, q_starts, ref.match_starts)
    np.testing.assert_array_equal(items, w_items)
    # naive loop: the score of item j is the sum over t of ||q[s + t] - frames[r_start_j + t]||
    np.testing.assert_allclose(scores, w_scores, rtol=1e-6)
    for m, s in enumerate(q_starts):  # naive loop: sum over t of ||q[s + t] - frames[r_start + t]||
        for rank_pos, j in enumerate(items[m]):
            r0 = ref.match_starts[j]
            naive = sum(float(torch.linalg.vector_norm(q[s + t] - frames[r0 + t])) for t in range(4))
            assert naive == pytest.approx(float(scores[m, rank_pos]), abs=1e-4)
