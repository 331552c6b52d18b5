"""A given matrix read in its own dtype, block by block (seqnet.search.given), answers as its float64 copy does."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import DatasetError
from seqnet.search import given as given_mod
from seqnet.search.blocks import topk_smallest
from seqnet.search.given import GivenMatrix


def readings(d):
    """The old reading of each orientation (argmin / argmax of the float64 distances' rows and columns)."""
    out = {"as given": d.argmin(1), "other sense": d.argmax(1)}
    if d.shape[0] == d.shape[1]:
        out |= {"transposed": d.argmin(0), "transposed, other sense": d.argmax(0)}
    return out


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64, np.int32])
@pytest.mark.parametrize("negate", [False, True])
@pytest.mark.parametrize("transposed", [False, True])
@pytest.mark.parametrize("shape", [(37, 37), (23, 41)])
@pytest.mark.parametrize("k", [1, 5])
def test_a_scan_equals_the_float64_matrix(dtype, negate, transposed, shape, k, monkeypatch):
    monkeypatch.setattr(given_mod, "SCAN_BYTES", 200)  # many blocks
    rng = np.random.default_rng(shape[1] + k)
    raw = rng.integers(-6, 7, shape).astype(dtype)  # many ties
    g = GivenMatrix(raw, negate, transposed)
    dense = (-1.0 if negate else 1.0) * raw.astype(np.float64)
    dense = dense.T if transposed else dense
    np.testing.assert_array_equal(g.dense(), dense)
    scan = g.scan(k)
    tv, ti = topk_smallest(torch.from_numpy(np.ascontiguousarray(dense)), k)
    np.testing.assert_array_equal(scan.topk[1], ti.numpy())
    np.testing.assert_array_equal(scan.topk[0], tv.numpy())
    assert scan.topk[0].dtype == np.float64
    want = readings(dense)
    assert set(scan.best) == set(want)
    for key, v in want.items():
        np.testing.assert_array_equal(scan.best[key], v, err_msg=key)
    q, r = np.array([3, 0, 5]), np.array([1, 2, 4, 0])
    np.testing.assert_array_equal(g[np.ix_(q, r)], dense[np.ix_(q, r)])


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_entry_is_named(bad, monkeypatch):
    monkeypatch.setattr(given_mod, "SCAN_BYTES", 100)
    raw = np.ones((20, 10), np.float32)
    raw[13, 7] = bad
    with pytest.raises(DatasetError, match=r"entry \[13, 7\]"):
        GivenMatrix(raw, where="m.npy").scan(3)
