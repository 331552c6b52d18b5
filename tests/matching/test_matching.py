"""Distance matrices, deterministic top-k and exact k-NN (torch blocks, FAISS) against loops."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from seqnet.core.errors import ConfigError
from seqnet.search.blocks import topk_smallest
from seqnet.search.knn import knn, pairwise_distances


def naive_topk(scores: np.ndarray, k: int):
    """k smallest per row, ties by lower column index (NaN ranks like +inf)."""
    vals, idx = [], []
    for row in scores:
        key = [(np.inf if np.isnan(v) else v, j) for j, v in enumerate(row)]
        best = sorted(key)[: min(k, len(row))]
        idx.append([j for _, j in best])
        vals.append([row[j] for _, j in best])
    return np.array(vals).reshape(len(scores), -1), np.array(idx, dtype=np.int64).reshape(len(scores), -1)


def naive_knn(q, r, k, metric="l2"):
    scores = np.array([[np.linalg.norm(a - b) if metric == "l2" else -(a @ b) for b in r] for a in q])
    v, i = naive_topk(scores, k)
    return (v if metric == "l2" else -v), i


# ----------------------------------------------------------------------------- pairwise_distances


@pytest.mark.parametrize("squared", [False, True])
def test_pairwise_distances_loop(rng, squared):
    q, r = rng.standard_normal((7, 5)), rng.standard_normal((9, 5))
    d = pairwise_distances(torch.from_numpy(q), torch.from_numpy(r), squared=squared).numpy()
    ref = np.array([[np.sum((a - b) ** 2) for b in r] for a in q])
    np.testing.assert_allclose(d, ref if squared else np.sqrt(ref), rtol=1e-10, atol=1e-10)


def test_pairwise_distances_identical_rows_not_negative(rng):
    x = torch.from_numpy(rng.standard_normal((6, 32)).astype(np.float32))
    d = pairwise_distances(x, x)
    assert (d >= 0).all() and not torch.isnan(d).any()
    assert torch.diagonal(d).abs().max() < 1e-2


# ----------------------------------------------------------------------------- topk_smallest


@pytest.mark.parametrize("k", [1, 3, 7, 20])
def test_topk_random(rng, k):
    s = rng.standard_normal((5, 11))
    v, i = topk_smallest(torch.from_numpy(s), k)
    nv, ni = naive_topk(s, k)
    np.testing.assert_array_equal(i.numpy(), ni)
    np.testing.assert_array_equal(v.numpy(), nv)


def test_topk_ties_lower_index_wins_also_at_cutoff():
    s = torch.tensor([[3.0, 1.0, 2.0, 1.0, 2.0, 2.0], [5.0, 5.0, 5.0, 5.0, 5.0, 5.0]])
    v, i = topk_smallest(s, 3)
    assert i.tolist() == [[1, 3, 2], [0, 1, 2]]  # cut-off among the 2.0s: column 2 before 4 and 5
    assert v.tolist() == [[1.0, 1.0, 2.0], [5.0, 5.0, 5.0]]


def test_topk_inf_and_nan():
    inf, nan = float("inf"), float("nan")
    s = torch.tensor([[nan, inf, 1.0, -inf, nan], [nan, nan, nan, nan, 0.0]])
    v, i = topk_smallest(s, 4)
    assert i.tolist() == [[3, 2, 0, 1], [4, 0, 1, 2]]
    assert v[0, :2].tolist() == [-inf, 1.0] and torch.isnan(v[0, 2]) and v[0, 3] == inf


def test_topk_edges():
    v, i = topk_smallest(torch.zeros((0, 4)), 2)
    assert v.shape == (0, 2) and i.dtype == torch.long
    v, i = topk_smallest(torch.ones((3, 4)), 0)
    assert v.shape == (3, 0)
    v, i = topk_smallest(torch.ones((2, 0)), 3)
    assert i.shape == (2, 0)
    v, i = topk_smallest(torch.tensor([[2, 1, 1]]), 2)  # integer scores
    assert i.tolist() == [[1, 2]]


@settings(max_examples=80, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 12)), elements=st.integers(0, 3).map(float)),
       st.integers(1, 14))
def test_topk_property_many_ties(scores, k):
    v, i = topk_smallest(torch.from_numpy(scores), k)
    nv, ni = naive_topk(scores, k)
    np.testing.assert_array_equal(i.numpy(), ni)
    np.testing.assert_array_equal(v.numpy(), nv)


# ----------------------------------------------------------------------------- knn


@pytest.mark.parametrize("metric", ["l2", "ip"])
@pytest.mark.parametrize("block_bytes", [None, 64])
def test_knn_torch_vs_loop(rng, metric, block_bytes):
    q, r = rng.standard_normal((13, 6)), rng.standard_normal((17, 6))
    v, i = knn(q, r, 5, metric=metric, device="cpu", block_bytes=block_bytes)
    nv, ni = naive_knn(q, r, 5, metric)
    np.testing.assert_array_equal(i, ni)
    np.testing.assert_allclose(v, nv, rtol=1e-9, atol=1e-9)
    assert v.dtype == np.float64  # float64 input stays float64


@pytest.mark.parametrize("metric", ["l2", "ip"])
def test_knn_faiss_vs_torch_vs_loop(rng, metric):
    q = rng.standard_normal((20, 8)).astype(np.float32)
    r = rng.standard_normal((30, 8)).astype(np.float32)
    tv, ti = knn(q, r, 4, backend="torch", metric=metric, device="cpu")
    fv, fi = knn(q, r, 4, backend="faiss", metric=metric)
    nv, ni = naive_knn(q.astype(np.float64), r.astype(np.float64), 4, metric)
    np.testing.assert_array_equal(ti, ni)
    np.testing.assert_array_equal(fi, ni)
    np.testing.assert_allclose(tv, nv, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(fv, nv, rtol=1e-4, atol=1e-4)


def test_knn_ties_lower_index(rng):
    # integer-valued data: every distance is computed exactly, so duplicated references tie exactly
    # (with arbitrary floats the GEMM may round identical columns differently in the last bit)
    r = np.repeat(rng.integers(-4, 5, (3, 4)).astype(np.float64), 3, axis=0)  # each reference three times
    q = r[[0, 4, 8]] + 1.0
    _, i = knn(q, r, 4, device="cpu")
    # within an exact tie the lower index wins; rows 0-2, 3-5 and 6-8 are tie groups
    assert i[0, :3].tolist() == [0, 1, 2] and i[1, :3].tolist() == [3, 4, 5] and i[2, :3].tolist() == [6, 7, 8]


def test_knn_caps_k_and_handles_empty(rng):
    q, r = rng.standard_normal((3, 4)), rng.standard_normal((2, 4))
    v, i = knn(q, r, 10, device="cpu")
    assert i.shape == (3, 2)
    v, i = knn(np.zeros((0, 4)), r, 3, device="cpu")
    assert v.shape == (0, 2) and i.shape == (0, 2)
    v, i = knn(np.zeros((0, 4), np.float32), r.astype(np.float32), 3, backend="faiss")
    assert i.shape == (0, 2)


def test_knn_torch_tensor_input(rng):
    q, r = rng.standard_normal((5, 3)).astype(np.float32), rng.standard_normal((6, 3)).astype(np.float32)
    v1, i1 = knn(q, r, 3, device="cpu")
    v2, i2 = knn(torch.from_numpy(q), torch.from_numpy(r), 3, device="cpu")
    np.testing.assert_array_equal(i1, i2)
    np.testing.assert_allclose(v1, v2)


def test_knn_read_only_input_no_warning(rng):
    q = rng.standard_normal((5, 3)).astype(np.float32)
    q.flags.writeable = False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        knn(q, q, 2, device="cpu")


@pytest.mark.parametrize("backend", ["torch", "faiss"])
def test_knn_errors(rng, backend):
    q, r = rng.standard_normal((3, 4)), rng.standard_normal((5, 3))
    with pytest.raises(ConfigError, match="dimension mismatch"):
        knn(q, r, 2, backend=backend, device="cpu")
    with pytest.raises(ConfigError, match=r"\[N, D\]"):
        knn(q[0], r, 2, backend=backend, device="cpu")
    with pytest.raises(ConfigError, match="k must be"):
        knn(q, q, 0, backend=backend)


def test_knn_bad_options(rng):
    q = rng.standard_normal((3, 4))
    with pytest.raises(ConfigError, match="backend"):
        knn(q, q, 2, backend="annoy")
    with pytest.raises(ConfigError, match="metric"):
        knn(q, q, 2, metric="cosine")
    with pytest.raises(ConfigError, match="must hold numbers"):
        knn(np.array([["a", "b"]]), q[:, :2], 1, device="cpu")


@pytest.mark.parametrize("col_block", [1, 3, 8, None])
@pytest.mark.parametrize("metric", ["l2", "ip"])
def test_knn_streams_reference_blocks(rng, col_block, metric):
    q, r = rng.standard_normal((17, 5)), rng.standard_normal((26, 5))
    a = knn(q, r, 6, metric=metric, device="cpu")
    from seqnet.search.knn import knn_torch

    b = knn_torch(q, r, 6, metric=metric, device="cpu", col_block=col_block, block_bytes=100)
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)


def test_knn_memmap_float16_reference(tmp_path, rng):
    r = rng.standard_normal((50, 4)).astype(np.float16)
    np.save(tmp_path / "r.npy", r)
    mm = np.load(tmp_path / "r.npy", mmap_mode="r")
    q = rng.standard_normal((7, 4)).astype(np.float32)
    from seqnet.search.knn import knn_torch

    a = knn_torch(q, mm, 5, device="cpu", col_block=8)
    b = knn(q, r.astype(np.float32), 5, device="cpu")
    np.testing.assert_array_equal(a[1], b[1])
