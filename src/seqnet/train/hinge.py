"""The triplet hinge on Euclidean distances as one autograd node with its gradient written out.

``Σ_t max(0, ‖q_a(t) − p_a(t) + ε‖ − ‖q_a(t) − n_t + ε‖ + m) / total`` (``F.pairwise_distance``'s ε, as
:func:`seqnet.train.losses.pair_distance`). Autograd would record about ten nodes for it (two gathers,
two norms, subtractions, the hinge, the sum and the division), each a pass over ``[T, D]`` in the
backward pass; here the backward pass is one expression over the active triplets::

    u_p = (q − p + ε) / d_pos,   u_n = (q_a − n + ε) / d_neg,   g_t = [hinge_t > 0] / total
    ∂/∂n_t = g_t·u_n(t),   ∂/∂p_b = −c_b·u_p(b),   ∂/∂q_b = c_b·u_p(b) − Σ_{t: a(t)=b} g_t·u_n(t)

with ``c_b = Σ_{t: a(t)=b} g_t``. The values are those of the autograd expression (the same operations
in the forward pass; the gradient up to float rounding).
"""

from __future__ import annotations

import functools

from ..core.lazy import lazy_module

torch = lazy_module("torch")


@functools.cache
def _function() -> type:
    """The :class:`torch.autograd.Function` (defined on first use: importing this module imports no torch)."""

    class TripletHinge(torch.autograd.Function):
        @staticmethod
        def forward(ctx, q, p, n, anchor, margin, denom, eps):  # noqa: ANN001, ANN205
            dp_vec = q - p + eps  # [B, D]
            dn_vec = q[anchor] - n + eps  # [T, D]
            d_pos, d_neg = dp_vec.norm(dim=1), dn_vec.norm(dim=1)
            hinge = torch.relu(d_pos[anchor] - d_neg + margin)
            ctx.save_for_backward(dp_vec, dn_vec, d_pos, d_neg, hinge, anchor)
            ctx.denom = denom
            ctx.mark_non_differentiable(hinge)
            return hinge.sum() / denom, hinge

        @staticmethod
        def backward(ctx, grad, _grad_hinge):  # noqa: ANN001, ANN205
            dp_vec, dn_vec, d_pos, d_neg, hinge, anchor = ctx.saved_tensors
            g = (hinge > 0).to(grad.dtype) * (grad / ctx.denom)  # [T]
            u_p = dp_vec / torch.where(d_pos > 0, d_pos, torch.ones_like(d_pos))[:, None]
            gn = dn_vec * (g / torch.where(d_neg > 0, d_neg, torch.ones_like(d_neg)))[:, None]  # ∂/∂n
            c = torch.zeros_like(d_pos).index_add_(0, anchor, g)  # [B]
            grad_p = u_p * -c[:, None]
            grad_q = (-grad_p).index_add_(0, anchor, gn, alpha=-1)
            return grad_q, grad_p, gn, None, None, None, None

    return TripletHinge


def triplet_hinge(q: torch.Tensor, p: torch.Tensor, n: torch.Tensor, anchor: torch.Tensor, margin: float,
                  denom: int, eps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(loss, hinge [T])``: the mean hinge over ``denom`` of the triplets (query ``q[anchor[t]]``, positive
    ``p[anchor[t]]``, negative ``n[t]``) with ``q, p [B, D]``, ``n [T, D]``, ``anchor [T]`` long; ``hinge`` is
    detached (no gradient flows through it)."""
    loss, hinge = _function().apply(q, p, n, anchor, float(margin), float(denom), float(eps))
    return loss, hinge.detach()
