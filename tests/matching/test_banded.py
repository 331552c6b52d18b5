"""The fused whole-map SeqMatch tiles (matching/banded) against naive loops, for every tiling."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.matching.banded import MIN_ROWS, TILE_BYTES, banded_map, tile_budget, tile_shape
from seqnet.matching.seqmatch import nan_free, seqmatch
from seqnet.matching.velocity import velocity_map


def naive(q, r, L, reverse=False):
    na, nb = len(q) - L + 1, len(r) - L + 1
    return np.array([[sum(float(np.linalg.norm(q[a + t] - r[b + (L - 1 - t if reverse else t)])) for t in range(L))
                      for b in range(nb)] for a in range(na)]).reshape(na, nb)


@settings(max_examples=40, deadline=None)
@given(nq=st.integers(1, 12), nr=st.integers(1, 12), L=st.integers(1, 5), reverse=st.booleans(),
       budget=st.integers(1, 800), seed=st.integers(0, 2**16))
def test_every_tiling_equals_the_loop(nq, nr, L, reverse, budget, seed):
    """Any tile budget (one window pair per tile up to the whole map): the naive loop's scores."""
    rng = np.random.default_rng(seed)
    q, r = rng.standard_normal((nq + L - 1, 3)), rng.standard_normal((nr + L - 1, 3))
    got = banded_map(torch.from_numpy(q), torch.from_numpy(r), L, reverse, budget).numpy()
    np.testing.assert_allclose(got, naive(q, r, L, reverse), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("L", [1, 2, 5])
@pytest.mark.parametrize("reverse", [False, True])
def test_tiles_carry_rows_and_split_columns(rng, L, reverse):
    """Tiles narrower than the map and shorter than L − 1 rows (the carried rows overlap their source)."""
    q, r = rng.standard_normal((40, 4)), rng.standard_normal((31, 4))
    want = naive(q, r, L, reverse)
    for budget in (8, 8 * 3 * (L + 1), 8 * 7 * 12, 8 * 50 * 40):
        got = seqmatch(q, r, L, reverse=reverse, device="cpu", tile_bytes=budget)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_float32_same_best_matches_as_float64(rng):
    """A route-like float32 map: the scores within float rounding of float64, the same argmin per query."""
    base = rng.standard_normal((200, 64))
    q = (base + 0.3 * rng.standard_normal(base.shape))[20:150]
    q64, r64 = q / np.linalg.norm(q, axis=1, keepdims=True), base / np.linalg.norm(base, axis=1, keepdims=True)
    m64 = seqmatch(q64, r64, 5, device="cpu")
    m32 = seqmatch(q64.astype(np.float32), r64.astype(np.float32), 5, device="cpu", tile_bytes=4096)
    assert m32.dtype == np.float32
    np.testing.assert_allclose(m32, m64, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(m32.argmin(1), m64.argmin(1))
    np.testing.assert_array_equal(m32.argmin(1), np.arange(20, 146))


def test_velocity_one_is_the_tiled_map(rng):
    """velocity_map and the tiles share the distance kernel and the adds: bit for bit where their GEMMs have
    the same shapes (here: one tile), within float rounding and with the same best matches where not."""
    q, r = rng.standard_normal((70, 16)).astype(np.float32), rng.standard_normal((3100, 16)).astype(np.float32)
    for reverse in (False, True):
        v = velocity_map(q, r, 5, (1,), reverse, "start", device="cpu")
        np.testing.assert_array_equal(seqmatch(q, r, 5, reverse=reverse, device="cpu"), v)
        narrow = seqmatch(q, r, 5, reverse=reverse, device="cpu", tile_bytes=30_000)
        np.testing.assert_allclose(narrow, v, rtol=1e-6, atol=0)
        np.testing.assert_array_equal(narrow.argmin(1), v.argmin(1))


def test_identical_windows_score_exactly_zero_and_ties_keep_the_lower_start():
    x = np.tile(np.arange(12.0).reshape(4, 3), (3, 1))  # period 4: windows 0, 4, 8 are the same
    m = seqmatch(x.astype(np.float32), x.astype(np.float32), 3, device="cpu", tile_bytes=64)
    assert m[0, 0] == m[0, 4] == m[0, 8] == 0.0 and m[4, 0] == 0.0
    assert m.argmin(1)[0] == 0 and (np.diag(m) == 0).all()


def test_too_short_and_bad_inputs(rng):
    q, r = rng.standard_normal((3, 4)), rng.standard_normal((6, 4))
    with pytest.raises(ConfigError, match="seq_len"):
        seqmatch(q, r, 4, device="cpu")  # N_q < L
    with pytest.raises(ConfigError, match="dimension mismatch"):
        seqmatch(q, rng.standard_normal((6, 5)), 2, device="cpu")
    bad = q.copy()
    bad[1, 2] = np.inf
    with pytest.raises(ConfigError, match="NaN or inf"):
        seqmatch(bad, r, 2, device="cpu")
    m = seqmatch(q, r, 3, device="cpu")
    assert m.shape == (1, 4)


def test_nan_check_only_where_norms_could_overflow():
    small, big = torch.ones(3), torch.full((3,), 1e38)
    assert nan_free(small, small, torch.float32) and not nan_free(big, small, torch.float32)
    assert nan_free(big, small, torch.float64) and not nan_free(torch.tensor([float("nan")]), small, torch.float64)
    # ‖q‖² ≈ 1.9e38 is finite in float32 but ‖q‖² + ‖r‖² is not: the result is checked, the NaN refused
    q = np.full((3, 3), 8e18, np.float32)
    with pytest.raises(ConfigError, match="hold NaN"):
        seqmatch(q, q, 2, device="cpu")


def test_tile_shapes_and_budgets():
    assert tile_shape(2996, 2996, 4, 4, TILE_BYTES) == (999, 2996)  # three balanced tiles of the whole width
    rows, width = tile_shape(5000, 100_000, 4, 4, TILE_BYTES)  # MIN_ROWS rows as wide as fit, balanced: 5 x 1000
    assert rows == 1000 and (MIN_ROWS + 4) * (width + 4) <= TILE_BYTES // 4 < (MIN_ROWS + 4) * (width + 5)
    assert tile_shape(10, 10, 0, 8, 1) == (1, 1)
    assert tile_budget(torch.device("cpu"), None, None) == TILE_BYTES
    assert tile_budget(torch.device("cpu"), None, 1000) == 1000 and tile_budget(torch.device("cpu"), 10, None) == 10
