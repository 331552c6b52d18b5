"""Triplet margin loss over a whole batch of (query, positive, negatives) at once.

SeqNet (like NetVLAD) trains with ``max(0, d(q, p) - d(q, n) + margin)`` on Euclidean distances of
L2-normalised descriptors, averaged over the triplets of a batch. The original code looped over
the triplets in Python; here all ``B × K`` triplets are one broadcast expression, and queries with
fewer than K mined negatives are handled by a validity mask.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from .errors import ConfigError

PAIRWISE_EPS = 1e-6  # as torch.nn.TripletMarginLoss / F.pairwise_distance


@dataclasses.dataclass
class TripletLoss:
    """Result of :func:`batch_triplet_loss`.

    Attributes:
        loss: scalar, mean hinge over the valid triplets (0 when there are none).
        triplets: number of valid triplets T.
        active: number of triplets with a positive hinge (they produce gradients).
        per_triplet: ``[B, K]`` hinge values (0 where not valid), detached.
    """

    loss: torch.Tensor
    triplets: int
    active: int
    per_triplet: torch.Tensor


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
        :class:`TripletLoss`; ``loss = Σ_valid max(0, ‖q−p‖ − ‖q−n‖ + m) / T`` — the same value as
        ``nn.TripletMarginLoss(margin, reduction="sum")`` summed over the triplets and divided by
        their number (the original SeqNet reduction).
    """
    if query.ndim != 2 or positive.shape != query.shape:
        raise ConfigError(f"query and positive must both be [B, D], got {tuple(query.shape)} and "
                          f"{tuple(positive.shape)}")
    b, d = query.shape
    if negatives.ndim != 3 or negatives.shape[0] != b or negatives.shape[2] != d:
        raise ConfigError(f"negatives must be [B={b}, K, D={d}], got {tuple(negatives.shape)}")
    if not margin > 0:
        raise ConfigError(f"margin must be > 0, got {margin}")
    if valid is None:
        valid = torch.ones(negatives.shape[:2], dtype=torch.bool, device=query.device)
    elif valid.shape != negatives.shape[:2]:
        raise ConfigError(f"valid must be [B, K] = {tuple(negatives.shape[:2])}, got {tuple(valid.shape)}")
    d_pos = F.pairwise_distance(query, positive, eps=PAIRWISE_EPS)  # [B]
    d_neg = F.pairwise_distance(query[:, None, :].expand_as(negatives), negatives, eps=PAIRWISE_EPS)  # [B, K]
    hinge = torch.where(valid, F.relu(d_pos[:, None] - d_neg + margin), torch.zeros_like(d_neg))
    n = int(valid.sum())
    loss = hinge.sum() / max(n, 1)
    return TripletLoss(loss, n, int((hinge > 0).sum()), hinge.detach())


def scatter_negatives(flat: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Place the descriptors of the valid negatives, ``[T, D]`` in row-major order of ``valid [B, K]``,
    into a padded ``[B, K, D]`` tensor (zeros where not valid); differentiable."""
    b, k = valid.shape
    if flat.shape[0] != int(valid.sum()):
        raise ConfigError(f"{flat.shape[0]} negative descriptors for {int(valid.sum())} valid slots")
    out = flat.new_zeros((b * k, flat.shape[1]))
    return out.index_put((valid.reshape(-1).nonzero()[:, 0],), flat).reshape(b, k, flat.shape[1])
