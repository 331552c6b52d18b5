"""The model-free descriptors in numpy (seqnet.sequence.npdescribed) equal the torch ones, batch by batch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.sequence.described import Described
from seqnet.sequence.descriptors import SEQUENCE_DESCRIPTORS
from seqnet.sequence.npdescribed import PLAIN_DESCRIPTORS, PlainDescribed, describe_np, l2_normalize_np
from seqnet.sequence.windows import Windows


@pytest.mark.parametrize("name", sorted(PLAIN_DESCRIPTORS))
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_window_functions_equal_torch(name, dtype):
    rng = np.random.default_rng(0)
    w = (rng.standard_normal((40, 5, 12)) * 3).astype(dtype)
    w[3] = 0  # a zero window stays zero
    w[4, :, 0] = 1e19 if dtype != np.int16 else 7  # large values do not overflow the norm
    got = PLAIN_DESCRIPTORS[name](w)
    want = SEQUENCE_DESCRIPTORS[name].fn(torch.from_numpy(w.astype(np.float32) if dtype == np.int16 else w))
    np.testing.assert_allclose(got.astype(np.float32), want.float().numpy(), rtol=1e-5, atol=1e-6)


def test_l2_normalize_keeps_float64_and_zero_rows():
    x = np.array([[3.0, 4.0], [0.0, 0.0]])
    assert l2_normalize_np(x).dtype == np.float64
    np.testing.assert_array_equal(l2_normalize_np(x), [[0.6, 0.8], [0.0, 0.0]])


@pytest.mark.parametrize("name", ["delta", "delta-paper"])
def test_delta_needs_two_frames(name):
    with pytest.raises(ConfigError, match="seq_len >= 2"):
        PLAIN_DESCRIPTORS[name](np.ones((2, 1, 3)))


def test_batches_and_spill_give_the_whole(monkeypatch, tmp_path):
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")
    monkeypatch.setenv("SEQNET_SPILL_DIR", str(tmp_path))
    rng = np.random.default_rng(1)
    raw = rng.standard_normal((300, 8))
    idx = np.arange(296)[:, None] + np.arange(5)
    whole = describe_np(raw, idx, "smoothing")
    small = describe_np(raw, idx, "smoothing", spill=True, block_bytes=5 * 8 * 8 * 7)
    assert whole.dtype == np.float32 and isinstance(whole, np.ndarray)
    np.testing.assert_array_equal(np.asarray(small), whole)


@pytest.mark.parametrize("name", sorted(PLAIN_DESCRIPTORS))
def test_plain_described_items_equal_described(name, synth_dataset):
    t = synth_dataset.query
    windows = Windows(seq_len=4, match_len=4, mode="centred")
    plain = PlainDescribed(t.descriptors, t.seq_bounds, windows)
    ref = Described(t.descriptors, t.seq_bounds, windows, {}, torch.device("cpu"))
    np.testing.assert_array_equal(plain.items_index, ref.items_index)
    np.testing.assert_allclose(plain.items(name), ref.items(name).numpy(), rtol=1e-5, atol=1e-6)
    assert plain.cost_ms([("items", name)]) >= 0.0
    with pytest.raises(ConfigError, match="item descriptors only"):
        plain.frames(name)


def test_inverse_norms_scale_rows_to_single(tmp_path):
    from seqnet.sequence.npdescribed import inverse_norms

    rng = np.random.default_rng(2)
    raw = rng.standard_normal((50, 6)).astype(np.float32)
    raw[7] = 0
    inv = inverse_norms(raw, block_bytes=64)
    assert inv[7] == 0
    np.testing.assert_allclose(raw * inv[:, None], describe_np(raw, np.arange(50)[:, None], "single"), atol=1e-6)
    big = raw.copy()
    big[3, 0] = 1e30  # its square overflows float32: describe it instead
    assert inverse_norms(big) is None
    assert inverse_norms(np.full((2, 3), 1e-30, np.float32)) is None  # squares underflow
    assert inverse_norms(np.full((2, 3), 1e30)) is not None  # float64 holds them
