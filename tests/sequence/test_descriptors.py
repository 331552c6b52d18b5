"""Smoothing, Delta descriptors, the SeqNet module and describe_windows against loops."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.sequence.descriptors import SEQUENCE_DESCRIPTORS, delta, delta_paper, describe_windows, smoothing
from seqnet.sequence.model import SeqNet
from seqnet.sequence.windows import window_indices


def unit(v):
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def naive_smoothing(w):
    return np.array([unit(np.mean([unit(f) for f in win], axis=0)) for win in w])


def naive_delta(w):
    out = []
    for win in w:
        L, h = len(win), len(win) // 2
        frames = [unit(f) for f in win]
        out.append(unit(np.mean(frames[L - h :], axis=0) - np.mean(frames[:h], axis=0)))
    return np.array(out)


@pytest.mark.parametrize("L", [1, 2, 3, 4, 5])
def test_smoothing_vs_loop(rng, L):
    w = rng.standard_normal((6, L, 8))
    out = smoothing(torch.from_numpy(w)).numpy()
    np.testing.assert_allclose(out, naive_smoothing(w), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)


@pytest.mark.parametrize("L", [2, 3, 4, 5, 8])
def test_delta_vs_loop(rng, L):
    w = rng.standard_normal((6, L, 8))
    out = delta(torch.from_numpy(w)).numpy()
    np.testing.assert_allclose(out, naive_delta(w), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)


def test_delta_odd_window_ignores_middle_frame(rng):
    w = torch.from_numpy(rng.standard_normal((3, 5, 4)))
    w2 = w.clone()
    w2[:, 2] = 100.0
    torch.testing.assert_close(delta(w), delta(w2))


def test_delta_needs_two_frames(rng):
    with pytest.raises(ConfigError, match="seq_len >= 2"):
        delta(torch.zeros((2, 1, 4)))


def test_zero_frames_stay_finite():
    w = torch.zeros((2, 3, 4))
    assert torch.isfinite(smoothing(w)).all() and torch.isfinite(delta(w)).all()


def test_sequence_descriptor_table():
    assert SEQUENCE_DESCRIPTORS["delta"].window_fn({}) is delta
    assert SEQUENCE_DESCRIPTORS["smoothing"].window_fn({}) is smoothing
    assert SEQUENCE_DESCRIPTORS["delta"].min_len == 2 and SEQUENCE_DESCRIPTORS["single"].length(5) == 1
    with pytest.raises(ConfigError, match="needs a trained S_L model"):
        SEQUENCE_DESCRIPTORS["seqnet"].window_fn({})
    model = SeqNet(4, 4, 1, 1)
    assert model.role == "s1" and SEQUENCE_DESCRIPTORS["s1"].window_fn({"s1": model}) is model
    assert SeqNet(4, 4, 5, 3).role == "seqnet"


@pytest.mark.parametrize("L", [2, 3, 4, 5, 6])
def test_delta_paper_vs_loop(rng, L):
    """The original code's Delta: weights +-1/(L/2), first L//2 negative, raw frames, then L2."""
    w = rng.standard_normal((4, L, 6))
    out = delta_paper(torch.from_numpy(w)).numpy()
    for m in range(4):
        acc = np.zeros(6)
        for t in range(L):
            acc += (-1.0 if t < L // 2 else 1.0) / (L / 2.0) * w[m, t]
        np.testing.assert_allclose(out[m], unit(acc), rtol=1e-9, atol=1e-12)
    if L == 5:  # the weights quoted in the docs: (-0.4, -0.4, +0.4, +0.4, +0.4)
        one = np.zeros((1, 5, 5))
        one[0, np.arange(5), np.arange(5)] = 1.0
        got = delta_paper(torch.from_numpy(one)).numpy()[0]
        np.testing.assert_allclose(got, unit(np.array([-0.4, -0.4, 0.4, 0.4, 0.4])), rtol=1e-9)
    with pytest.raises(ConfigError, match="seq_len >= 2"):
        delta_paper(torch.zeros(2, 1, 3))


# ----------------------------------------------------------------------------- SeqNet


def test_seqnet_matches_manual_conv(rng):
    torch.manual_seed(0)
    model = SeqNet(in_dims=6, out_dims=4, seq_len=5, w=3)
    x = torch.from_numpy(rng.standard_normal((3, 5, 6)).astype(np.float32))
    y = model(x)
    W, b = model.conv.weight.detach().numpy(), model.conv.bias.detach().numpy()  # [4, 6, 3], [4]
    xn = x.numpy()
    for i in range(3):
        outs = [sum(W[:, :, k] @ xn[i, s + k] for k in range(3)) + b for s in range(5 - 3 + 1)]
        np.testing.assert_allclose(y[i].detach().numpy(), unit(np.mean(outs, axis=0)), rtol=1e-5, atol=1e-6)
    assert model.config() == {"in_dims": 6, "out_dims": 4, "seq_len": 5, "w": 3}


def test_s1_accepts_2d_input(rng):
    model = SeqNet(5, 7, 1, 1)
    x = torch.from_numpy(rng.standard_normal((4, 5)).astype(np.float32))
    y = model(x)
    assert y.shape == (4, 7)
    torch.testing.assert_close(y, model(x[:, None, :]))
    torch.testing.assert_close(y.norm(dim=1), torch.ones(4))


def test_seqnet_errors():
    with pytest.raises(ConfigError, match="w <= seq_len"):
        SeqNet(4, 4, 3, 4)
    with pytest.raises(ConfigError, match="w <= seq_len"):
        SeqNet(4, 4, 3, 0)
    with pytest.raises(ConfigError, match="dims"):
        SeqNet(0, 4, 3, 2)
    model = SeqNet(4, 4, 3, 3)
    with pytest.raises(ConfigError, match="expects D=4"):
        model(torch.zeros((1, 3, 5)))
    with pytest.raises(ConfigError, match="needs windows"):
        model(torch.zeros((1, 2, 4)))


# ----------------------------------------------------------------------------- describe_windows


@pytest.mark.parametrize("fn", [smoothing, delta])
@pytest.mark.parametrize("batch_size", [1, 3, 4096])
def test_describe_windows_vs_direct(rng, fn, batch_size):
    desc = rng.standard_normal((20, 6)).astype(np.float32)
    idx = window_indices(20, 4, "centred")
    out = describe_windows(desc, idx, fn, batch_size=batch_size)
    direct = fn(torch.from_numpy(desc)[torch.from_numpy(idx)])
    assert out.dtype == torch.float32 and out.shape == (20, 6)
    torch.testing.assert_close(out, direct)


def test_describe_windows_with_model_and_memmap(rng, tmp_path):
    desc = rng.standard_normal((12, 5)).astype(np.float32)
    np.save(tmp_path / "d.npy", desc)
    mm = np.load(tmp_path / "d.npy", mmap_mode="r")  # read-only memory map
    model = SeqNet(5, 3, 3, 2).eval()
    idx = window_indices(12, 3, "causal")
    out = describe_windows(mm, idx, model, batch_size=5)
    with torch.no_grad():
        direct = model(torch.from_numpy(desc)[torch.from_numpy(idx)])
    torch.testing.assert_close(out, direct)


def test_describe_windows_empty_keeps_output_width():
    desc = np.zeros((5, 4), np.float32)
    assert describe_windows(desc, np.zeros((0, 3), np.int64), SeqNet(4, 7, 3, 2)).shape == (0, 7)
    assert describe_windows(desc, np.zeros((0, 3), np.int64), smoothing).shape == (0, 4)
    with pytest.raises(ConfigError, match=r"\[M, L\]"):
        describe_windows(desc, np.zeros(3, np.int64), smoothing)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 15), L=st.integers(2, 6), d=st.integers(1, 5), seed=st.integers(0, 2**16))
def test_sequence_descriptor_property(n, L, d, seed):
    rng = np.random.default_rng(seed)
    desc = rng.standard_normal((n, d))
    idx = window_indices(n, L, "centred")
    w = desc[idx]
    # float64: the vectorised functions equal the loops
    np.testing.assert_allclose(smoothing(torch.from_numpy(w)).numpy(), naive_smoothing(w), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(delta(torch.from_numpy(w)).numpy(), naive_delta(w), rtol=1e-9, atol=1e-12)
    # describe_windows (float32, batches, de-duplicated rows) equals the function on gathered windows
    w32 = torch.from_numpy(desc.astype(np.float32))[torch.from_numpy(idx)]
    for fn in (smoothing, delta):
        torch.testing.assert_close(describe_windows(desc, idx, fn, batch_size=4), fn(w32), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("seq_len,w", [(1, 1), (5, 3), (10, 5), (4, 4), (6, 1)])
def test_seqnet_gemm_forward_equals_conv(seq_len, w):
    torch.manual_seed(0)
    model = SeqNet(12, 9, seq_len, w)
    x = torch.randn(7, seq_len, 12)
    assert torch.allclose(model(x), model.forward_conv(x), atol=1e-6)
    # and the gradients agree, so training with the GEMM form trains the same network
    g1 = torch.autograd.grad(model(x).sum(), model.conv.weight)[0]
    g2 = torch.autograd.grad(model.forward_conv(x).sum(), model.conv.weight)[0]
    assert torch.allclose(g1, g2, atol=1e-5)


@pytest.mark.parametrize("fn", [smoothing, delta, delta_paper])
def test_one_window_is_refused_with_the_leading_axis_hint(fn):
    """A single window [L, D] was read as L windows of D one-dimensional frames and gave [L] silently."""
    with pytest.raises(ConfigError, match=r"\[M, L, D\].*\(5, 64\).*x\[None\]"):
        fn(torch.randn(5, 64))


@pytest.mark.parametrize("fn, naive", [(smoothing, naive_smoothing), (delta, naive_delta)])
def test_numpy_windows_give_numpy_equal_to_the_loop(fn, naive):
    """numpy windows raised AttributeError ('numpy.ndarray' object has no attribute 'abs')."""
    w = np.random.default_rng(0).standard_normal((3, 5, 8)).astype(np.float32)
    out = fn(w)
    assert isinstance(out, np.ndarray) and out.shape == (3, 8)
    np.testing.assert_allclose(out, naive(w), atol=1e-5)
    np.testing.assert_allclose(out, fn(torch.from_numpy(w)).numpy(), atol=1e-6)
