"""Described (one traverse's items and frames) against a naive per-window loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.sequence.described import Described, describe_frames
from seqnet.sequence.descriptors import delta, smoothing
from seqnet.sequence.windows import Windows


@pytest.mark.parametrize("mode", ["centred", "causal"])
def test_items_and_frames_equal_a_loop(rng, mode):
    x = rng.standard_normal((30, 6)).astype(np.float32)
    bounds = np.array([[0, 12]] * 12 + [[12, 30]] * 18)
    w = Windows(4, 5, mode)
    d = Described(x, bounds, w, {}, torch.device("cpu"))
    off = 2 if mode == "centred" else 3  # L // 2, or L - 1
    m_off = 2 if mode == "centred" else 4
    want_items = [i for i in range(30) if bounds[i, 0] <= i - off and i - off + 4 <= bounds[i, 1]
                  and bounds[i, 0] <= i - m_off and i - m_off + 5 <= bounds[i, 1]]
    assert d.side.items.tolist() == want_items
    items = d.items("smoothing").numpy()
    for row, i in zip(items, want_items, strict=True):
        np.testing.assert_allclose(row, smoothing(torch.from_numpy(x[i - off : i - off + 4])[None])[0], rtol=1e-5)
    frames = d.frames("delta").numpy()
    for i in range(30):  # every frame's window, clamped into its sequence
        idx = np.clip(np.arange(i - off, i - off + 4), bounds[i, 0], bounds[i, 1] - 1)
        np.testing.assert_allclose(frames[i], delta(torch.from_numpy(x[idx])[None])[0], rtol=1e-5, atol=1e-6)
    single = d.frames("single").numpy()  # the frame's own descriptor (normalised), indexed for the items
    np.testing.assert_array_equal(d.items("single").numpy(), single[want_items])
    np.testing.assert_allclose(single, x / np.linalg.norm(x, axis=1, keepdims=True), rtol=1e-5)
    assert d.time_ms("items", "single") >= d.time_ms("frames", "single")


def test_the_newest_frame_alone_equals_the_batch(rng):
    x = rng.standard_normal((9, 6)).astype(np.float32)
    w = Windows(4, 4, "causal")
    batch = describe_frames(x, None, "delta", w, {}, torch.device("cpu"))
    for n in range(1, 10):
        last = describe_frames(torch.from_numpy(x[max(0, n - 4) : n]), None, "delta", w, {}, torch.device("cpu"),
                               which=np.array([min(n, 4) - 1]))
        np.testing.assert_allclose(last[0], batch[n - 1], rtol=1e-5, atol=1e-6)


def test_no_item_is_a_clear_error():
    with pytest.raises(ConfigError, match="no query frame has a full window of seq_len=5"):
        Described(np.zeros((3, 2), np.float32), None, Windows(5, 5), {}, torch.device("cpu"))


def test_one_window_in_memory_equals_the_gather_for_any_indices(rng):
    """describe_windows' one-window path (a view of a run, else a gather) equals the batched path."""
    from seqnet.sequence.descriptors import describe_windows

    x = torch.from_numpy(rng.standard_normal((9, 6)).astype(np.float32))
    for frames in ([2, 3, 4, 5], [0, 0, 1, 2], [0, 5, 2, 3], [7, 6, 5, 4]):
        idx = np.array([frames])
        one = describe_windows(x, idx, smoothing)
        two = describe_windows(x, np.vstack([idx, idx]), smoothing)[:1]  # two windows: the batched path
        np.testing.assert_allclose(one.numpy(), two.numpy(), rtol=1e-6)
