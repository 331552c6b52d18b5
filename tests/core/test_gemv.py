"""The per-frame GEMV: every kernel of the table equals a naive loop; what it cannot take goes to torch.mv."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core import gemv


@pytest.mark.parametrize("kernel", list(gemv.GEMV_KERNELS))
@pytest.mark.parametrize(("rows", "cols"), [(1, 1), (7, 3), (33, 130), (0, 4)])
def test_every_kernel_equals_a_loop(monkeypatch, kernel, rows, cols):
    monkeypatch.setenv("SEQNET_GEMV", kernel)
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    rng = np.random.default_rng(rows * 100 + cols)
    m, v = rng.standard_normal((rows, cols)).astype(np.float32), rng.standard_normal(cols).astype(np.float32)
    naive = np.array([sum(float(m[i, j]) * float(v[j]) for j in range(cols)) for i in range(rows)])
    out = gemv.matvec(torch.from_numpy(m), torch.from_numpy(v))
    assert out.dtype == torch.float32 and out.shape == (rows,)
    np.testing.assert_allclose(out.numpy(), naive, rtol=1e-5, atol=1e-5)


def test_what_the_blas_kernel_cannot_take_runs_on_torch(monkeypatch):
    calls = []
    monkeypatch.setitem(gemv.GEMV_KERNELS, "blas", lambda m, v: calls.append(1) or torch.mv(m, v))
    monkeypatch.delenv("SEQNET_GEMV", raising=False)
    m, v = torch.randn(5, 4), torch.randn(4)
    gemv.matvec(m, v)  # small: torch
    assert calls == [] and gemv.kernel_name() == "blas"
    monkeypatch.setattr(gemv, "BLAS_MIN_BYTES", 0)
    gemv.matvec(m, v)
    assert calls == [1]
    w = torch.randn(5, 4, requires_grad=True)
    y = gemv.matvec(w, v)  # autograd: torch's kernel, the gradient flows
    y.sum().backward()
    torch.testing.assert_close(w.grad, v.expand(5, 4))
    gemv.matvec(m.half(), v.half())
    gemv.matvec(m.T.contiguous().T, v)  # not contiguous
    assert calls == [1]
    monkeypatch.setenv("SEQNET_GEMV", "nosuch")
    assert gemv.kernel_name() == "blas"


def test_a_seqnet_window_and_a_batch_give_one_descriptor():
    """S_L of one window (the GEMV) equals the same window inside a batch (the GEMM)."""
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    model = SeqNet(16, 8, 5, 3).eval()
    x = torch.randn(4, 5, 16)
    with torch.no_grad():
        torch.testing.assert_close(model(x[2:3]), model(x)[2:3], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(model(x), model.forward_conv(x), rtol=1e-5, atol=1e-6)
