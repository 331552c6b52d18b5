"""The one blocked-search driver and its top-k: both top-k paths (a stable sort for short rows, topk with
tie handling for long ones) against a naive loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import seqnet.search.blocks as blocks


def naive_topk(scores: np.ndarray, k: int) -> np.ndarray:
    key = np.where(np.isnan(scores), np.inf, scores)
    return np.stack([sorted(range(len(r)), key=lambda j, r=r: (r[j], j))[:k] for r in key])


@pytest.mark.parametrize("sort_max", [0, 10**9])  # the topk path, the sort path
@pytest.mark.parametrize("shape,k", [((3, 50), 7), ((1, 9), 9), ((4, 300), 1)])
def test_both_topk_paths_equal_a_loop_with_ties_and_nan(monkeypatch, rng, sort_max, shape, k):
    monkeypatch.setattr(blocks, "SORT_MAX", sort_max)
    x = rng.integers(0, 6, shape).astype(np.float32)  # many ties
    x[0, ::7] = np.nan
    v, i = blocks.topk_smallest(torch.from_numpy(x), k)
    np.testing.assert_array_equal(i.numpy(), naive_topk(x, k))
    np.testing.assert_array_equal(v.numpy(), np.take_along_axis(x, naive_topk(x, k), 1))


def test_the_driver_merges_blocks_as_one_row(rng):
    x = torch.from_numpy(rng.integers(0, 9, (5, 40)).astype(np.float32))
    cols = [(0, 13), (13, 27), (27, 40)]

    def score(rows, cb):
        return x[rows][:, cb[0] : cb[1]], torch.arange(*cb)

    got = blocks.blocked_topk([(torch.tensor([3, 4]), [3, 4]), (slice(0, 3), [0, 1, 2])], cols, score, 5, 6,
                              torch.float32)
    np.testing.assert_array_equal(got[1], naive_topk(x.numpy(), 6))
    with pytest.raises(Exception, match="not finite"):
        bad = x.clone()
        bad[1, 3] = float("nan")
        blocks.blocked_topk([(slice(0, 5), list(range(5)))], cols,
                            lambda r, cb: (bad[r][:, cb[0] : cb[1]], torch.arange(*cb)), 5, 3, torch.float32)


@st.composite
def tied_scores(draw):
    """Rows of few distinct values (runs of ties at every cut-off), sometimes inf / NaN, and a k."""
    b, n = draw(st.integers(1, 6)), draw(st.integers(1, 90))
    pool = draw(st.lists(st.sampled_from([0.0, -0.0, 1.0, 2.5, -3.0, np.inf, -np.inf, np.nan]), min_size=1, max_size=4))
    x = np.array(draw(st.lists(st.sampled_from(pool), min_size=b * n, max_size=b * n)), np.float32).reshape(b, n)
    return x, draw(st.integers(1, n + 2))


@settings(max_examples=120, deadline=None)
@given(tied_scores(), st.sampled_from([0, 10**9]))
def test_topk_equals_a_stable_argsort_whatever_the_ties(case, sort_max):
    x, k = case
    old = blocks.SORT_MAX
    blocks.SORT_MAX = sort_max
    try:
        v, i = blocks.topk_smallest(torch.from_numpy(x), k)
    finally:
        blocks.SORT_MAX = old
    want = naive_topk(x, k)
    np.testing.assert_array_equal(i.numpy(), want)
    np.testing.assert_array_equal(v.numpy(), np.take_along_axis(x, want, 1))


@settings(max_examples=50, deadline=None)
@given(tied_scores(), st.integers(1, 30))
def test_merged_blocks_equal_a_stable_argsort_of_the_whole_row(case, width):
    x, k = case
    k = min(k, x.shape[1])
    t = torch.from_numpy(x)
    best = None
    for c0 in range(0, x.shape[1], width):
        cols = torch.arange(c0, min(x.shape[1], c0 + width))
        best = blocks.merge_topk(best, t[:, c0 : c0 + width], cols if c0 else None, k)
    np.testing.assert_array_equal(best[1].numpy(), naive_topk(x, k))
