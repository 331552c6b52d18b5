"""The per-frame GEMV: every kernel of the table equals a naive loop; the fastest is chosen per dtype and
shape on this machine; what the kernels cannot take goes to torch.mv."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core import gemv


@pytest.fixture(autouse=True)
def _fresh_choices(monkeypatch):
    monkeypatch.setattr(gemv, "_CHOSEN", {})


def _naive(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.array([sum(float(m[i, j]) * float(v[j]) for j in range(m.shape[1])) for i in range(m.shape[0])])


@pytest.mark.parametrize("kernel", list(gemv.GEMV_KERNELS))
@pytest.mark.parametrize(("rows", "cols"), [(1, 1), (7, 3), (33, 130), (0, 4)])
def test_every_kernel_equals_a_loop(monkeypatch, kernel, rows, cols):
    monkeypatch.setenv("SEQNET_GEMV", kernel)
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    rng = np.random.default_rng(rows * 100 + cols)
    m, v = rng.standard_normal((rows, cols)).astype(np.float32), rng.standard_normal(cols).astype(np.float32)
    out = gemv.matvec(torch.from_numpy(m), torch.from_numpy(v))
    assert out.dtype == torch.float32 and out.shape == (rows,)
    np.testing.assert_allclose(out.numpy(), _naive(m, v), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_kernels_equal_a_loop(monkeypatch, dtype):
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    m, v = torch.randn(40, 70).to(dtype), torch.randn(70).to(dtype)
    naive = _naive(m.float().numpy(), v.float().numpy())
    assert gemv.candidates(dtype) == ["torch", "linear"]  # no NumPy half GEMV
    for kernel in gemv.candidates(dtype):
        monkeypatch.setenv("SEQNET_GEMV", kernel)
        out = gemv.matvec(m, v)
        assert out.dtype == dtype
        np.testing.assert_allclose(out.float().numpy(), naive, rtol=2e-2, atol=0.2)


def test_the_fastest_kernel_is_chosen_once_per_dtype_and_shape(monkeypatch):
    monkeypatch.delenv("SEQNET_GEMV", raising=False)
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    fake = {"torch": 3.0, "linear": 1.0, "blas": 2.0}
    timed = []
    monkeypatch.setattr(gemv, "_seconds", lambda k, m, v: timed.append(m.dtype) or fake[_name(k)])
    m, v = torch.randn(6, 5), torch.randn(5)
    assert gemv.kernel_for(m, v) == "linear" and len(timed) == 3
    assert gemv.kernel_for(m, v) == "linear" and len(timed) == 3  # remembered
    fake["linear"] = 9.0
    assert gemv.kernel_for(torch.randn(6, 4), torch.randn(4)) == "blas"  # another shape: timed again
    assert gemv.kernel_for(m.half(), v.half()) == "torch" and len(timed) == 8  # blas does not take float16
    assert set(gemv.chosen().values()) == {"linear", "blas", "torch"}
    assert "float16 [6, 5] x" in " ".join(gemv.chosen())
    monkeypatch.setenv("SEQNET_GEMV", "blas")
    assert gemv.kernel_for(m, v) == "blas" and gemv.kernel_for(m.half(), v.half()) == "torch"  # blas: f32 only


def _name(kernel) -> str:
    return next(k for k, f in gemv.GEMV_KERNELS.items() if f is kernel)


def test_tuning_times_the_real_kernels(monkeypatch):
    monkeypatch.delenv("SEQNET_GEMV", raising=False)
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    m, v = torch.randn(64, 32), torch.randn(32)
    assert gemv.kernel_for(m, v) in gemv.candidates(torch.float32)
    assert gemv._seconds(gemv.GEMV_KERNELS["torch"], m, v) > 0


def test_what_the_kernels_cannot_take_runs_on_torch(monkeypatch):
    calls = []
    for name in gemv.GEMV_KERNELS:
        monkeypatch.setitem(gemv.GEMV_KERNELS, name, lambda m, v: calls.append(1) or torch.mv(m, v))
    monkeypatch.setenv("SEQNET_GEMV", "blas")
    m, v = torch.randn(5, 4), torch.randn(4)
    gemv.matvec(m, v)  # small: torch, untuned
    assert calls == [] and gemv.chosen() == {}
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    gemv.matvec(m, v)
    assert calls == [1]
    w = torch.randn(5, 4, requires_grad=True)
    y = gemv.matvec(w, v)  # autograd: torch's kernel, the gradient flows
    y.sum().backward()
    torch.testing.assert_close(w.grad, v.expand(5, 4))
    gemv.matvec(m.T.contiguous().T, v)  # not contiguous
    with pytest.raises(RuntimeError, match="dtype"):  # mixed dtypes: not tuned, torch says what is wrong
        gemv.matvec(m.half(), v.float())
    assert calls == [1]


def test_a_seqnet_window_and_a_batch_give_one_descriptor():
    """S_L of one window (the GEMV) equals the same window inside a batch (the GEMM)."""
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    model = SeqNet(16, 8, 5, 3).eval()
    x = torch.randn(4, 5, 16)
    with torch.no_grad():
        torch.testing.assert_close(model(x[2:3]), model(x)[2:3], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(model(x), model.forward_conv(x), rtol=1e-5, atol=1e-6)
