"""The path dynamic program of graph sequence matching (GISM-style), shared by the offline and online graph
matchers (:mod:`seqnet.matching.graph`) and the graph training loss (:mod:`seqnet.train.losses`).

A path of reference frames moves by ``0 .. fan_out`` frames per query step; :func:`runmin` is one transition
(a running minimum over ``fan_out`` shifted columns), :func:`path_dp` the cheapest path through each column
at a pivot step. Both run in place on the matchers' hot path and out of place when autograd needs the
values (a loss on path costs).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from ..core.lazy import lazy_module

torch = lazy_module("torch")


def runmin(x: torch.Tensor, fan_out: int, backward: bool = False) -> torch.Tensor:
    """``out[..., j] = min_{s = 0..fan_out} x[..., j − s]`` (``j + s`` when ``backward``), in range only.

    In place over shifted slices; when ``x`` needs a gradient (a training loss on path costs,
    :mod:`seqnet.train.losses`), the same minimum out of place, so that autograd follows it."""
    if torch.is_grad_enabled() and x.requires_grad:
        return _runmin_autograd(x, fan_out, backward)
    out = x.clone()
    for s in range(1, min(fan_out, x.shape[-1] - 1) + 1):
        if backward:
            torch.minimum(out[..., :-s], x[..., s:], out=out[..., :-s])
        else:
            torch.minimum(out[..., s:], x[..., :-s], out=out[..., s:])
    return out


def _runmin_autograd(x: torch.Tensor, fan_out: int, backward: bool) -> torch.Tensor:
    n = min(fan_out, x.shape[-1] - 1)
    pad = torch.nn.functional.pad(x, (0, n) if backward else (n, 0), value=math.inf)
    w = x.shape[-1]
    shifts = [pad[..., s : s + w] if backward else pad[..., n - s : n - s + w] for s in range(n + 1)]
    return torch.stack(shifts).amin(dim=0)


def path_dp(step: Callable[[int], torch.Tensor], seq_len: int, fan_out: int, pivot: int,
            start_mask: torch.Tensor | None = None) -> torch.Tensor:
    """Cheapest path cost through each column at step ``pivot`` (see the module docstring).

    ``step(t)`` gives the distances ``[..., W]`` of query step t to the W columns; columns are
    consecutive reference frames. ``start_mask [..., W]`` (bool): where a path may start (step 0).
    """
    fwd = step(0).clone()
    if start_mask is not None:
        fwd.masked_fill_(~start_mask, math.inf)
    for t in range(1, pivot + 1):
        fwd = _add(runmin(fwd, fan_out), step(t))
    if pivot < seq_len - 1:
        bwd = step(seq_len - 1).clone()
        for t in range(seq_len - 2, pivot, -1):
            bwd = _add(runmin(bwd, fan_out, backward=True), step(t))
        fwd = _add(fwd, runmin(bwd, fan_out, backward=True))
    return fwd


def _add(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a + b``, in place into ``a`` unless autograd needs ``a`` as it is (the minimum's backward reads it)."""
    return a + b if torch.is_grad_enabled() and (a.requires_grad or b.requires_grad) else a.add_(b)
