"""The numpy top-k (seqnet.search.nptopk) equals a stable argsort and the torch top-k, ties and NaN included; so does
the bound-based merge_smallest, block by block."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from seqnet.search.blocks import topk_smallest
from seqnet.search.nptopk import finished, merge_distances, merge_smallest, merge_topk_np, topk_smallest_np

# few distinct values: runs of ties everywhere; ±0, ±inf and NaN
VALUES = st.sampled_from([0.0, -0.0, 1.0, 2.0, 2.0, 3.0, -1.0, np.inf, -np.inf, np.nan])


def naive(x, k):
    key = np.where(np.isnan(x), np.inf, x)
    idx = np.argsort(key, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(x, idx, 1), idx


@settings(max_examples=150, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 6), st.integers(1, 90)), elements=VALUES), st.integers(1, 95))
def test_topk_equals_a_stable_argsort_and_torch(x, k):
    v, i = topk_smallest_np(x, k)
    nv, ni = naive(x, min(k, x.shape[1]))
    np.testing.assert_array_equal(i, ni)
    np.testing.assert_array_equal(v, nv)
    tv, ti = topk_smallest(torch.from_numpy(x), k)
    np.testing.assert_array_equal(i, ti.numpy())


@settings(max_examples=80, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(2, 120)), elements=VALUES.map(np.float32)),
       st.integers(1, 30), st.integers(1, 50))
def test_blocks_merged_equal_the_whole_row(x, k, width):
    best = None
    for c in range(0, x.shape[1], width):
        best = merge_topk_np(best, x[:, c:c + width], c, k)
    nv, ni = naive(x, min(k, x.shape[1]))
    np.testing.assert_array_equal(best[1], ni)
    np.testing.assert_array_equal(best[0], nv)


def test_large_rows_with_ties_at_the_cut_off():
    rng = np.random.default_rng(0)
    x = rng.integers(0, 20, (50, 3000)).astype(np.float32)  # every cut-off inside a run of ties
    for k in (1, 7, 100):
        np.testing.assert_array_equal(topk_smallest_np(x, k)[1], naive(x, k)[1])
    y = rng.standard_normal((40, 5000))
    np.testing.assert_array_equal(topk_smallest_np(y, 20)[1], naive(y, 20)[1])


def merged(x, k, width, merge):
    best = None
    for c in range(0, x.shape[1], width):
        best = merge(best, x[:, c:c + width], c, k)
    return best


@settings(max_examples=120, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(0, 5), st.integers(1, 400)), elements=VALUES.map(np.float32)),
       st.integers(1, 30), st.integers(1, 400))
def test_merge_smallest_equals_a_stable_argsort(x, k, width):
    """Runs of ties at the cut-off, ±0, ±inf and NaN (rows whose bound is not finite take the sort), any block width."""
    got = merged(x, k, width, merge_smallest)
    nv, ni = naive(x, min(k, x.shape[1]))
    np.testing.assert_array_equal(got[1], ni)
    np.testing.assert_array_equal(got[0], nv)


def test_merge_smallest_on_route_like_rows_and_ties():
    """Wide rows whose nearest columns are neighbours (a route: one strided group each), and integer rows tied
    everywhere, in blocks: the same answer as a stable argsort and as merge_topk_np."""
    rng = np.random.default_rng(1)
    cols = np.arange(5000)
    x = (np.abs(cols[None, :] - rng.integers(0, 5000, 30)[:, None]) + rng.random((30, 5000))).astype(np.float32)
    ties = rng.integers(0, 9, (30, 5000)).astype(np.float32)
    for y in (x, ties, -ties):
        for k, width in ((1, 5000), (20, 5000), (20, 1777), (300, 2048)):
            got = merged(y, k, width, merge_smallest)
            np.testing.assert_array_equal(got[1], naive(y, k)[1])
            np.testing.assert_array_equal(got[1], merged(y, k, width, merge_topk_np)[1])


def merged_distances(u, add, k, width):
    best = None
    for c in range(0, u.shape[1], width):
        best = merge_distances(best, u[:, c:c + width], add, c, k)
    return best


def by_finishing(u, add, k, width):
    """The reference: every entry finished, then merge_smallest (and a stable argsort of the finished rows)."""
    return merged(finished(u, add), k, width, merge_smallest)


U_VALUES = st.sampled_from([0.0, -0.0, 1.0, 2.0, 2.0, -1.0, -3.0, 1e-30, np.inf, -np.inf, np.nan])


@settings(max_examples=150, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(0, 5), st.integers(1, 400)), elements=U_VALUES.map(np.float32)),
       st.lists(st.sampled_from([0.0, 1.0, 2.0, 3.5, 1e-3]), min_size=5, max_size=5), st.integers(1, 30),
       st.integers(1, 400))
def test_merge_distances_equals_finishing_every_entry(u, add, k, width):
    """Negative sums clamped to 0 (ties), ±inf, NaN, any block width: the answer of finishing every entry first."""
    add = np.asarray(add[: len(u)], np.float32)
    got, want = merged_distances(u, add, k, width), by_finishing(u, add, k, width)
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], naive(finished(u, add), min(k, u.shape[1]))[1])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_merge_distances_where_the_root_makes_ties(dtype):
    """Squared distances a few units in the last place apart, whose roots round to the same value: the ties of the
    finished distances go to the lower column, also across the cut-off (the inverse threshold is generous)."""
    rng = np.random.default_rng(2)
    base = rng.uniform(0.5, 3.0, (40, 1)).astype(dtype)
    steps = rng.integers(0, 6, (40, 3000)).astype(dtype)
    u = base * (1 + steps * np.finfo(dtype).eps) - dtype(1.0)  # u + 1 within 6 ulp of base: many equal roots
    add = np.ones(40, dtype)
    u[:, ::97] -= dtype(0.25)  # a few clear winners in strided groups
    for k, width in ((1, 3000), (20, 3000), (20, 1024), (200, 700)):
        got, want = merged_distances(u, add, k, width), by_finishing(u, add, k, width)
        np.testing.assert_array_equal(got[1], want[1])
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], naive(finished(u, add), k)[1])


def test_merge_distances_on_route_like_rows():
    rng = np.random.default_rng(3)
    cols = np.arange(6000)
    d2 = (np.abs(cols[None, :] - rng.integers(0, 6000, 25)[:, None]) / 6000 + rng.random((25, 6000)) * 1e-3)
    add = rng.uniform(0.9, 1.1, 25)
    u = (d2 - add[:, None]).astype(np.float32)
    add = add.astype(np.float32)
    for k, width in ((20, 4096), (5, 6000), (256, 1500)):
        got = merged_distances(u, add, k, width)
        np.testing.assert_array_equal(got[1], naive(finished(u, add), k)[1])
        np.testing.assert_array_equal(got[0], by_finishing(u, add, k, width)[0])
