"""The one blocked-search driver and its top-k: both top-k paths (a stable sort for short rows, topk with
tie handling for long ones) against a naive loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch

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
