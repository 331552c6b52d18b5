"""The numpy exact search (seqnet.search.npexact) against a naive loop and the torch ExactIndex: ties, NaN, k > N,
tiny data, blocks, the inner-product metric, and the float64 re-run when a best score fails its check."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from seqnet.core.errors import ConfigError
from seqnet.search import npexact
from seqnet.search.knn import ExactIndex
from seqnet.search.npexact import NumpyExactIndex


def naive(q, r, k, metric="l2"):
    """One query at a time, float64, a stable sort: (scores, indices) best first, ties by the lower index."""
    vals, idx, k = [], [], min(k, len(r))
    for row in np.asarray(q, np.float64):
        s = -(np.asarray(r, np.float64) @ row) if metric == "ip" else np.linalg.norm(r - row, axis=1)
        order = np.argsort(s, kind="stable")[:k]
        vals.append(-s[order] if metric == "ip" else s[order])
        idx.append(order)
    return np.array(vals).reshape(len(q), k), np.array(idx, dtype=np.int64).reshape(len(q), k)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 12), st.just(3)), elements=st.integers(-3, 3).map(float)),
       arrays(np.float64, st.tuples(st.integers(0, 5), st.just(3)), elements=st.integers(-3, 3).map(float)),
       st.integers(1, 15), st.sampled_from(["l2", "ip"]))
def test_integer_data_equals_the_naive_loop_and_torch(r, q, k, metric):
    """Integer-valued float64 rows: every distance exact, ties everywhere, k > N capped."""
    v, i = NumpyExactIndex(r, block_bytes=64).search(q, k, metric)
    nv, ni = naive(q, r, min(k, len(r)), metric)
    np.testing.assert_array_equal(i, ni)
    np.testing.assert_allclose(v, nv, atol=1e-12)
    tv, ti = ExactIndex(r, "cpu", block_bytes=64, col_block=2).search(q, k, metric)
    np.testing.assert_array_equal(i, ti)


@pytest.mark.parametrize("block_bytes", [None, 1 << 18])
def test_float32_blocks_equal_torch(block_bytes):
    """Normalised float32 descriptors, one block or many: the torch index's indices, its scores to rounding."""
    rng = np.random.default_rng(0)
    r = rng.standard_normal((3000, 64)).astype(np.float32)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    q = r[rng.choice(3000, 150)] + 0.05 * rng.standard_normal((150, 64)).astype(np.float32)
    v, i = NumpyExactIndex(r, block_bytes).search(q, 20)
    tv, ti = ExactIndex(r, "cpu", block_bytes).search(q, 20)
    np.testing.assert_array_equal(i, ti)
    np.testing.assert_allclose(v, tv, atol=2e-6)
    assert v.dtype == np.float32 and i.dtype == np.int64
    nv, ni = naive(q, r, 20)
    np.testing.assert_array_equal(i, ni)


def test_memory_mapped_reference(tmp_path):
    rng = np.random.default_rng(2)
    r = rng.standard_normal((500, 16)).astype(np.float32)
    np.save(tmp_path / "r.npy", r)
    mm = np.load(tmp_path / "r.npy", mmap_mode="r")
    q = rng.standard_normal((7, 16)).astype(np.float32)
    np.testing.assert_array_equal(NumpyExactIndex(mm, 4096).search(q, 5)[1], naive(q, r, 5)[1])


def test_empty_and_tiny():
    r = np.eye(3, dtype=np.float32)
    v, i = NumpyExactIndex(r).search(np.zeros((0, 3), np.float32), 5)
    assert v.shape == (0, 3) and i.shape == (0, 3)
    v, i = NumpyExactIndex(r).search(r[:1], 10)  # k > N: capped
    assert i.tolist() == [[0, 1, 2]] and v[0, 0] == 0.0 and np.allclose(v[0, 1:], np.sqrt(2))
    v, i = NumpyExactIndex(np.zeros((0, 3), np.float32)).search(r, 4)
    assert v.shape == (3, 0)


@pytest.mark.parametrize("side", ["query", "reference"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e30])
def test_non_finite_rows_are_refused(side, bad):
    r, q = np.ones((5, 4), np.float32), np.ones((2, 4), np.float32)
    (q if side == "query" else r)[1, 2] = bad
    with pytest.raises(ConfigError, match=f"the {side} descriptors hold NaN or inf"):
        NumpyExactIndex(r).search(q, 2)


def test_dimension_mismatch_and_non_arrays():
    with pytest.raises(ConfigError, match="dimension mismatch"):
        NumpyExactIndex(np.ones((3, 4))).search(np.ones((1, 5)), 1)
    with pytest.raises(ConfigError, match="numpy array"):
        NumpyExactIndex([[1.0, 2.0]])


def test_a_failed_check_runs_the_search_again_in_float64(monkeypatch, caplog):
    """A kernel's wrong best score (simulated: the check names a row) makes the whole search run in float64."""
    rng = np.random.default_rng(3)
    r, q = rng.standard_normal((300, 32)).astype(np.float32), rng.standard_normal((9, 32)).astype(np.float32)
    calls = []
    real = NumpyExactIndex._search

    def spy(self, query, k, metric, dtype):
        calls.append(dtype)
        return real(self, query, k, metric, dtype)

    monkeypatch.setattr(NumpyExactIndex, "_search", spy)
    monkeypatch.setattr(npexact, "wrong_rows", lambda *a: np.array([4]))
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        v, i = NumpyExactIndex(r).search(q, 6)
    assert calls == [np.float32, np.float64] and "run again in float64" in caplog.text
    nv, ni = naive(q, r, 6)
    np.testing.assert_array_equal(i, ni)
    assert v.dtype == np.float32


def test_row_scale_searches_the_scaled_rows():
    """``row_scale``: the rows ``ref[i] * s[i]`` (single's normalised rows without a copy), checked as such."""
    rng = np.random.default_rng(4)
    r = rng.standard_normal((700, 24)) * rng.uniform(0.1, 9, (700, 1))
    q = rng.standard_normal((30, 24)).astype(np.float32)
    s = 1 / np.linalg.norm(r, axis=1)
    v, i = NumpyExactIndex(r, 1 << 14, row_scale=s, dtype=np.float32).search(q, 8)
    want = (r * s[:, None]).astype(np.float32)
    wv, wi = NumpyExactIndex(want, 1 << 14).search(q, 8)
    np.testing.assert_array_equal(i, wi)
    np.testing.assert_allclose(v, wv, atol=2e-6)
    assert v.dtype == np.float32
    with pytest.raises(ConfigError, match="row_scale"):
        NumpyExactIndex(r, row_scale=s[:5])
