"""The SeqNet model (Garg & Milford, RA-L 2021): S_L, and S_1 as ``L = w = 1``.

Conv1d over time (D → D_out, kernel w, bias, no padding, stride 1), mean over the ``L - w + 1``
outputs, L2 norm; computed as one GEMM (:meth:`SeqNet.forward`) equal to the literal convolution
(:meth:`SeqNet.forward_conv`). The window functions that use it are in :mod:`.descriptors`.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from torch import nn

from ..core.errors import ConfigError
from ..core.gemv import matvec


@functools.lru_cache(maxsize=16)
def _tap_average(seq_len: int, w: int) -> torch.Tensor:
    """``[w, L]``: entry ``[k, l]`` is ``1/T`` when frame ``l`` meets filter tap ``k`` at one of the
    ``T = L − w + 1`` positions of the convolution, else 0."""
    tap = torch.arange(seq_len)[None, :] - torch.arange(w)[:, None]
    t = seq_len - w + 1
    return ((tap >= 0) & (tap < t)).float() / t


class SeqNet(nn.Module):
    """SeqNet S_L: ``[B, L, D]`` (or ``[B, D]`` for S_1) → L2-normalised ``[B, D_out]``."""

    def __init__(self, in_dims: int, out_dims: int, seq_len: int, w: int) -> None:
        super().__init__()
        if not 1 <= w <= seq_len:
            raise ConfigError(f"SeqNet needs 1 <= w <= seq_len, got w={w}, seq_len={seq_len}")
        if in_dims < 1 or out_dims < 1:
            raise ConfigError(f"SeqNet dims must be >= 1, got in_dims={in_dims}, out_dims={out_dims}")
        self.in_dims, self.out_dims, self.seq_len, self.w = in_dims, out_dims, seq_len, w
        self.conv = nn.Conv1d(in_dims, out_dims, kernel_size=w, bias=True)
        self.provenance: dict | None = None  # how the descriptors it was trained on were made
        self.trained_on: dict | None = None  # {"dataset": dir, "split": name, "checkpoint": path} of its training

    def _check(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim == 2:
            x = x[:, None, :]
        if x.shape[-1] != self.in_dims:
            raise ConfigError(f"SeqNet expects D={self.in_dims} inputs, got D={x.shape[-1]}")
        if x.shape[1] < self.w:
            raise ConfigError(f"SeqNet with w={self.w} needs windows of >= {self.w} frames, got {x.shape[1]}")
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[B, L, D]`` → ``[B, D_out]``, computed as one GEMM (same value as :meth:`forward_conv`).

        The network is linear up to its L2 norm: the mean over the ``T = L − w + 1`` outputs of the
        convolution is ``b + Σ_k W_k · mean_{t<T} x[t + k]``. So the windows are averaged per filter
        tap first (``[B, w, D]``) and multiplied once by the ``[D_out, D·w]`` weight, T times fewer
        multiplications than the convolution.
        """
        weight = self.conv.weight
        x = self._check(x).to(weight.dtype)  # a half-precision model (to(torch.bfloat16)) reads half the bytes
        # [B, w, D]; with w = L (S_L at full width, S_1) the tap average is the identity: the windows themselves
        per_tap = x if x.shape[1] == self.w else _tap_average(x.shape[1], self.w).to(x.device, x.dtype) @ x
        if self.packed:
            y = self._tap_products(per_tap)
        else:
            shifted = per_tap.transpose(1, 2).reshape(len(x), self.in_dims * self.w)  # [B, D·w], D-major as the weight
            flat = weight.reshape(self.out_dims, -1)
            if len(shifted) == 1:  # one window (a frame of a stream): a GEMV on the fastest kernel
                y = (matvec(flat, shifted[0]) + self.conv.bias)[None]
            else:
                y = F.linear(shifted, flat, self.conv.bias)
        return F.normalize(y.to(torch.promote_types(y.dtype, torch.float32)), dim=-1)  # normalised in >= float32

    @property
    def packed(self) -> bool:
        """Whether the weight is stored tap-major (:meth:`pack_taps`)."""
        return self.w > 1 and self.conv.weight.permute(2, 0, 1).is_contiguous()

    def pack_taps(self) -> SeqNet:
        """Store the weight tap-major (``[w, D_out, D]`` contiguous, seen as the usual ``[D_out, D, w]``; same
        values, same checkpoints) for windows described one at a time: a window is then ``w`` products with
        contiguous ``[D_out, D]`` blocks, which CPU GEMV kernels read nearer memory speed than the one wide
        ``[D_out, D·w]`` product (torch reads a wide float16 matrix at about half its float32 rate per byte).
        ``LocalizeConfig.localizer`` packs the localiser's models; returns ``self``."""
        if self.w > 1 and not self.packed:
            taps = self.conv.weight.detach().permute(2, 0, 1).contiguous()
            self.conv.weight = nn.Parameter(taps.permute(1, 2, 0), requires_grad=self.conv.weight.requires_grad)
        return self

    def _tap_products(self, per_tap: torch.Tensor) -> torch.Tensor:
        """``b + Σ_k W_k · per_tap[:, k]`` (``[B, w, D]`` → ``[B, D_out]``), packed weight, summed in >= float32."""
        taps = self.conv.weight.permute(2, 0, 1)  # [w, D_out, D], contiguous
        acc = torch.promote_types(taps.dtype, torch.float32)
        if len(per_tap) == 1:
            y = sum(matvec(taps[k], per_tap[0, k].contiguous()).to(acc) for k in range(self.w))[None]
        else:
            y = sum(F.linear(per_tap[:, k], taps[k]).to(acc) for k in range(self.w))
        return y + self.conv.bias.to(acc)

    def forward_conv(self, x: torch.Tensor) -> torch.Tensor:
        """The literal SeqNet forward: Conv1d over time, mean over time, L2 norm (``[B, L, D]`` → ``[B, D_out]``)."""
        y = self.conv(self._check(x).permute(0, 2, 1))  # [B, D_out, L - w + 1]
        return F.normalize(y.mean(dim=-1), dim=-1)

    @property
    def role(self) -> str:
        """``"s1"`` for an S_1 model (``seq_len == w == 1``), else ``"seqnet"`` (S_L)."""
        return "s1" if self.seq_len == 1 and self.w == 1 else "seqnet"

    def config(self) -> dict[str, int]:
        """Architecture hyper-parameters (stored in checkpoints)."""
        return {"in_dims": self.in_dims, "out_dims": self.out_dims, "seq_len": self.seq_len, "w": self.w}
