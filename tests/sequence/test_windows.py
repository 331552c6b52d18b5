"""Sequence windows: starts, validity and indices against a naive loop, plus properties."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.sequence.windows import (
    check_seq_len,
    check_speed_range,
    gather_windows,
    speed_windows,
    window_indices,
    window_offset,
    window_starts,
)


def bounds_from_cuts(n: int, cuts) -> np.ndarray:
    """``[n, 2]`` sequence bounds for sequences split at ``cuts``."""
    edges = [0, *sorted({c for c in cuts if 0 < c < n}), n]
    b = np.zeros((n, 2), dtype=np.int64)
    for a, e in zip(edges[:-1], edges[1:], strict=True):
        b[a:e] = (a, e)
    return b


def naive_windows(n, L, mode, bounds):
    starts, valid, idx = [], [], []
    for i in range(n):
        lo, hi = (0, n) if bounds is None else bounds[i]
        s = i - (L // 2 if mode == "centred" else L - 1)
        starts.append(s)
        valid.append(lo <= s and s + L <= hi)
        idx.append([min(max(s + t, lo), hi - 1) for t in range(L)])
    return np.array(starts), np.array(valid, dtype=bool), np.array(idx).reshape(n, L)


@pytest.mark.parametrize("mode", ["centred", "causal"])
@pytest.mark.parametrize("L", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("with_bounds", [False, True])
def test_against_loop(mode, L, with_bounds, rng):
    n = 40
    bounds = bounds_from_cuts(n, rng.integers(1, n, 4)) if with_bounds else None
    starts, valid = window_starts(n, L, mode, bounds)
    idx = window_indices(n, L, mode, bounds)
    n_starts, n_valid, n_idx = naive_windows(n, L, mode, bounds)
    np.testing.assert_array_equal(starts, n_starts)
    np.testing.assert_array_equal(valid, n_valid)
    np.testing.assert_array_equal(idx, n_idx)
    assert starts.dtype == np.int64 and valid.dtype == bool and idx.shape == (n, L)


def test_offsets():
    assert window_offset(5, "centred") == 2 and window_offset(5, "causal") == 4
    assert window_offset(4, "centred") == 2 and window_offset(1, "centred") == 0 and window_offset(1, "causal") == 0
    with pytest.raises(ConfigError, match="window mode"):
        window_offset(3, "middle")


def test_l1_every_frame_valid():
    starts, valid = window_starts(7, 1, "centred")
    np.testing.assert_array_equal(starts, np.arange(7))
    assert valid.all()
    np.testing.assert_array_equal(window_indices(7, 1), np.arange(7)[:, None])


def test_l_equal_to_length():
    _, valid = window_starts(5, 5, "centred")
    np.testing.assert_array_equal(np.flatnonzero(valid), [2])
    _, valid = window_starts(5, 5, "causal")
    np.testing.assert_array_equal(np.flatnonzero(valid), [4])


def test_l_longer_than_traverse_all_invalid():
    starts, valid = window_starts(3, 5, "centred")
    assert not valid.any()
    idx = window_indices(3, 5, "centred")
    assert idx.min() >= 0 and idx.max() <= 2  # replicate-padded into the traverse


def test_bounds_make_every_window_invalid():
    bounds = bounds_from_cuts(12, [2, 4, 6, 8, 10])  # sequences of 2 frames
    _, valid = window_starts(12, 3, "centred", bounds)
    assert not valid.any()
    idx = window_indices(12, 3, "centred", bounds)
    assert ((idx >= bounds[:, :1]) & (idx < bounds[:, 1:])).all()


def test_empty_traverse():
    starts, valid = window_starts(0, 3)
    assert starts.shape == (0,) and valid.shape == (0,)
    assert window_indices(0, 3).shape == (0, 3)


@pytest.mark.parametrize("bad", [0, -1, 2.0, "3", None, True])
def test_bad_seq_len(bad):
    with pytest.raises(ConfigError, match="seq_len"):
        window_starts(10, bad)


def test_check_seq_len():
    assert check_seq_len(np.int64(3), 3) == 3
    with pytest.raises(ConfigError, match="longer than the traverse"):
        check_seq_len(4, 3)


def test_bad_bounds_shape():
    with pytest.raises(ConfigError, match="seq_bounds"):
        window_starts(5, 2, "centred", np.zeros((4, 2), np.int64))


def test_gather_windows():
    desc = torch.arange(12.0).reshape(6, 2)
    idx = window_indices(6, 3, "centred")
    w = gather_windows(desc, idx)
    assert w.shape == (6, 3, 2)
    for i in range(6):
        for t in range(3):
            assert torch.equal(w[i, t], desc[idx[i, t]])


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(0, 30),
    L=st.integers(1, 9),
    mode=st.sampled_from(["centred", "causal"]),
    cuts=st.lists(st.integers(1, 29), max_size=5),
)
def test_window_properties(n, L, mode, cuts):
    bounds = bounds_from_cuts(n, cuts) if n else None
    starts, valid = window_starts(n, L, mode, bounds)
    idx = window_indices(n, L, mode, bounds)
    lo, hi = (np.zeros(n, int), np.full(n, n)) if bounds is None else (bounds[:, 0], bounds[:, 1])
    # every index lies in the frame's own sequence; every window contains its frame
    assert ((idx >= lo[:, None]) & (idx < hi[:, None])).all()
    assert (idx == np.arange(n)[:, None]).any(axis=1).all() if n else True
    # valid windows are exactly the L consecutive frames from their start, inside the sequence
    for i in np.flatnonzero(valid):
        np.testing.assert_array_equal(idx[i], np.arange(starts[i], starts[i] + L))
        assert lo[i] <= starts[i] and starts[i] + L <= hi[i]
    # the number of valid windows per sequence is max(0, length - L + 1)
    seqs = {tuple(b) for b in np.stack([lo, hi], 1).tolist()}
    assert valid.sum() == sum(max(0, e - s - L + 1) for s, e in seqs)


def naive_speed_window(i, L, mode, v, lo, hi):
    """The specification, literally: offsets round(t·v) (half up) from the start i − round(a·v); the usual
    window when that leaves the sequence [lo, hi)."""
    a = L // 2 if mode == "centred" else L - 1

    def half_up(x):
        return int(np.floor(x + 0.5))

    frames = [i - half_up(a * v) + half_up(t * v) for t in range(L)]
    if min(frames) < lo or max(frames) >= hi:
        frames = [i - a + t for t in range(L)]
    return frames


@pytest.mark.parametrize("mode", ["centred", "causal"])
@pytest.mark.parametrize("L", [1, 2, 5, 6])
def test_speed_windows_against_the_specification(mode, L, rng):
    n = 60
    bounds = bounds_from_cuts(n, [25])
    _, valid = window_starts(n, L, mode, bounds)
    items = np.flatnonzero(valid)
    speeds = np.exp(rng.uniform(np.log(0.5), np.log(2.0), len(items)))
    speeds[:4] = [0.5, 1.0, 1.5, 2.0]  # exact halves: round half up
    got = speed_windows(items, L, mode, speeds, bounds[items])
    expected = [naive_speed_window(i, L, mode, v, *bounds[i]) for i, v in zip(items, speeds, strict=True)]
    np.testing.assert_array_equal(got, np.array(expected).reshape(len(items), L))
    usual = window_indices(n, L, mode, bounds)[items]
    np.testing.assert_array_equal(speed_windows(items, L, mode, np.ones(len(items)), bounds[items]), usual)
    anchor = window_offset(L, mode)
    np.testing.assert_array_equal(got[:, anchor], items)  # the window's own frame stays in its place
    if L > 2:
        assert (got != usual).any()  # the speeds change windows (the test can fail)
        assert (np.diff(got, axis=1) == 0).any() and (np.diff(got, axis=1) >= 2).any()  # slower and faster


def test_speed_windows_example():
    # centred L = 5 at frame 10: v = 2 -> 6, 8, 10, 12, 14; v = 0.5 -> round half up of 0, .5, 1, 1.5, 2
    got = speed_windows(np.array([10, 10, 2]), 5, "centred", np.array([2.0, 0.5, 2.0]), np.array([[0, 30]] * 3))
    np.testing.assert_array_equal(got, [[6, 8, 10, 12, 14], [9, 10, 10, 11, 11], [0, 1, 2, 3, 4]])


@pytest.mark.parametrize("bad", [(0, 1), (2, 1), "0.5:2", (1,), (1, float("nan"))])
def test_bad_speed_range(bad):
    with pytest.raises(ConfigError, match="speed"):
        check_speed_range("speed", bad)
