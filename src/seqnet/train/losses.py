"""Triplet margin loss over a whole batch of (query, positive, negatives) at once.

SeqNet (like NetVLAD) trains with ``max(0, d(q, p) - d(q, n) + margin)`` on Euclidean distances of
L2-normalised descriptors, averaged over the triplets of a batch. The original code looped over
the triplets in Python; here all ``B × K`` triplets are one broadcast expression, and queries with
fewer than K mined negatives are handled by a validity mask (or by listing the T valid triplets).
"""

from __future__ import annotations

import dataclasses

from ..core.errors import ConfigError
from ..core.lazy import lazy_module

torch = lazy_module("torch")
F = lazy_module("torch.nn.functional")

PAIRWISE_EPS = 1e-6  # as torch.nn.TripletMarginLoss / F.pairwise_distance


@dataclasses.dataclass
class TripletLoss:
    """Result of :func:`batch_triplet_loss`.

    Attributes:
        loss: scalar, mean hinge over the valid triplets (0 when there are none).
        triplets: number of valid triplets T.
        active: number of triplets with a positive hinge (they produce gradients).
        per_triplet: the hinge of each triplet (``[T]``, or ``[B, K]`` with 0 where not valid), detached.
    """

    loss: torch.Tensor
    triplets: int
    active: int
    per_triplet: torch.Tensor


def triplet_loss(
    query: torch.Tensor, positive: torch.Tensor, negatives: torch.Tensor, anchor: torch.Tensor, margin: float,
    total: int | None = None,
) -> TripletLoss:
    """Triplet margin loss of T triplets given as (query ``anchor[t]``, its positive, negative ``t``).

    Args:
        query: ``[B, D]`` query descriptors; positive: ``[B, D]`` one positive per query.
        negatives: ``[T, D]`` the negatives of all triplets.
        anchor: ``[T]`` long, the query (row of ``query``) of each negative.
        margin: hinge margin m > 0 on Euclidean distances.
        total: the number of triplets the mean is over (default T; distributed training: those of the
            whole batch, so that the losses of its shares sum to the batch's mean).

    Returns:
        :class:`TripletLoss` with ``per_triplet`` of shape ``[T]``; ``loss = Σ_t max(0, ‖q−p‖ − ‖q−n_t‖ + m) / T``.
    """
    if query.ndim != 2 or positive.shape != query.shape:
        raise ConfigError(f"query and positive must both be [B, D], got {tuple(query.shape)} and "
                          f"{tuple(positive.shape)}")
    if negatives.ndim != 2 or negatives.shape[1] != query.shape[1] or anchor.shape != negatives.shape[:1]:
        raise ConfigError(f"negatives must be [T, D={query.shape[1]}] with anchor [T], got {tuple(negatives.shape)} "
                          f"and {tuple(anchor.shape)}")
    if not margin > 0:
        raise ConfigError(f"margin must be > 0, got {margin}")
    if total is not None and total < max(int(anchor.numel()), 1):
        raise ConfigError(f"total must be >= the {anchor.numel()} triplets given (and >= 1), got {total}")
    d_pos = F.pairwise_distance(query, positive, eps=PAIRWISE_EPS)  # [B]
    d_neg = F.pairwise_distance(query[anchor], negatives, eps=PAIRWISE_EPS)  # [T]
    hinge = F.relu(d_pos[anchor] - d_neg + margin)
    n = int(anchor.numel())
    return TripletLoss(hinge.sum() / (max(n, 1) if total is None else total), n, int((hinge > 0).sum()),
                       hinge.detach())


def batch_triplet_loss(
    query: torch.Tensor,
    positive: torch.Tensor,
    negatives: torch.Tensor,
    margin: float,
    valid: torch.Tensor | None = None,
) -> TripletLoss:
    """Triplet margin loss of every (query b, positive b, negative b k) at once.

    Args:
        query: ``[B, D]`` query descriptors.
        positive: ``[B, D]`` one positive per query.
        negatives: ``[B, K, D]`` negatives per query (rows beyond a query's count are padding).
        margin: hinge margin m > 0 on Euclidean distances.
        valid: ``[B, K]`` bool, which negatives are real (default: all).

    Returns:
        :class:`TripletLoss` (``per_triplet`` ``[B, K]``, 0 where not valid);
        ``loss = Σ_valid max(0, ‖q−p‖ − ‖q−n‖ + m) / T`` — the same value as
        ``nn.TripletMarginLoss(margin, reduction="sum")`` summed over the T triplets and divided by
        T (the original SeqNet reduction).
    """
    if negatives.ndim != 3 or negatives.shape[0] != query.shape[0] or negatives.shape[2] != query.shape[-1]:
        raise ConfigError(f"negatives must be [B={query.shape[0]}, K, D={query.shape[-1]}], "
                          f"got {tuple(negatives.shape)}")
    if valid is None:
        valid = torch.ones(negatives.shape[:2], dtype=torch.bool, device=query.device)
    elif valid.shape != negatives.shape[:2]:
        raise ConfigError(f"valid must be [B, K] = {tuple(negatives.shape[:2])}, got {tuple(valid.shape)}")
    out = triplet_loss(query, positive, negatives[valid], valid.nonzero()[:, 0], margin)
    per = out.per_triplet.new_zeros(valid.shape)
    per[valid] = out.per_triplet
    out.per_triplet = per
    return out
