"""Triplet margin loss over a whole batch of (query, positive, negatives) at once, and the table of losses.

SeqNet (like NetVLAD) trains with ``max(0, d(q, p) - d(q, n) + margin)`` on Euclidean distances of
L2-normalised descriptors, averaged over the triplets of a batch. The original code looped over
the triplets in Python; here all ``B × K`` triplets are one broadcast expression, and queries with
fewer than K mined negatives are handled by a validity mask (or by listing the T valid triplets).

:data:`LOSSES` names what ``d`` is (``seqnet train --loss``): ``triplet`` — the distance of the two
windows' descriptors (the paper's); ``seqmatch`` — SeqMatchNet-style (Garg, Vankadari & Milford,
CoRL 2021), the SeqMatch score of two L_m-frame windows of S_1 descriptors,
``s(q, r) = Σ_t ‖S_1(q_t) − S_1(r_t)‖`` (S_1 outputs L2-normalised), so that S_1 is trained for what
SeqMatch does with it; the positive and the hard negatives are mined by that score too;
``vseqmatch`` — the same with the velocity-robust score of :mod:`seqnet.matching.velocity` (the minimum over
its trajectories, differentiable almost everywhere: the gradient flows through the best trajectory), for
which each reference window is widened by the frames the steepest trajectory reaches (:func:`velocity_pad`);
``graph`` — the graph matcher's path cost (:mod:`seqnet.matching.graph`, GISM-style: the cheapest path
with steps 0..fan_out through the window's centre, the :mod:`~seqnet.matching.paths` dynamic program run
with autograd; a minimum of sums, so differentiable almost everywhere, the gradient along the cheapest
path), on reference windows widened to the frames such paths reach (:func:`graph_pad`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..matching.graph import DEFAULT_FAN_OUT
from ..matching.paths import path_dp
from ..matching.velocity import DEFAULT_VELOCITIES, trajectories
from ..search.knn import pairwise_distances
from .hinge import triplet_hinge

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


def pair_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Euclidean distance of matching rows: ``[T, D]`` × ``[T, D]`` → ``[T]``."""
    return F.pairwise_distance(a, b, eps=PAIRWISE_EPS)


def seqmatch_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """SeqMatch score of matching windows: ``[T, L, D]`` × ``[T, L, D]`` → ``[T]``, ``Σ_t ‖a_t − b_t‖``."""
    return F.pairwise_distance(a, b, eps=PAIRWISE_EPS).sum(dim=-1)


@functools.cache
def velocity_pad(window_len: int) -> int:
    """Frames the velocity-robust trajectories (:data:`~seqnet.matching.velocity.DEFAULT_VELOCITIES`, centre
    anchor) reach beyond an L-frame reference window, on either side: ``[L + 2·pad]`` windows hold them all."""
    offs = np.array(trajectories(DEFAULT_VELOCITIES, window_len, "centre"))
    return int(max(0, -offs.min(), offs.max() - (window_len - 1)))


def _offsets(window_len: int, ref_len: int) -> list[tuple[int, ...]]:
    """Each trajectory's frames in an ``ref_len``-frame reference window centred like the ``window_len`` one."""
    pad = (ref_len - window_len) // 2
    if ref_len != window_len + 2 * velocity_pad(window_len):
        raise ConfigError(f"vseqmatch: reference windows of {window_len}-frame queries must have "
                          f"{window_len + 2 * velocity_pad(window_len)} frames, got {ref_len}")
    return [tuple(o + pad for o in offs) for offs in trajectories(DEFAULT_VELOCITIES, window_len, "centre")]


def vseqmatch_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Velocity-robust SeqMatch score of matching windows: ``a [T, L, D]`` × ``b [T, L + 2·pad, D]`` → ``[T]``,
    ``min_v Σ_t ‖a_t − b_{traj_v(t)}‖`` (as :func:`seqnet.matching.velocity.velocity_pairs` on the frames)."""
    scores = [F.pairwise_distance(a, b[:, list(offs)], eps=PAIRWISE_EPS).sum(dim=-1)
              for offs in _offsets(a.shape[1], b.shape[1])]
    return torch.stack(scores).amin(dim=0)


def cross_vseqmatch(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Velocity-robust scores of every pair: ``[S, L, D]`` × ``[R, L + 2·pad, D]`` → ``[S, R]``; each distinct
    (step, reference frame) distance computed once."""
    dist: dict[tuple[int, int], torch.Tensor] = {}
    best = None
    for offs in _offsets(q.shape[1], r.shape[1]):
        for t, o in enumerate(offs):
            if (t, o) not in dist:
                dist[t, o] = pairwise_distances(q[:, t], r[:, o])
        score = sum(dist[t, o] for t, o in enumerate(offs))
        best = score if best is None else torch.minimum(best, score)
    return best


@functools.cache
def graph_pad(window_len: int) -> int:
    """Frames the graph matcher's paths (steps 0..:data:`~seqnet.matching.graph.DEFAULT_FAN_OUT` through the
    centre frame) reach beyond an L-frame reference window, on either side."""
    p = window_len // 2
    return max(p, window_len - 1 - p) * max(0, DEFAULT_FAN_OUT - 1)


def _graph_cost(step: Callable[[int], torch.Tensor], window_len: int, ref_len: int) -> torch.Tensor:
    """The cheapest path's cost through the wide window's centre frame at the pivot step (``step(t)``: the
    distances ``[..., ref_len]`` of query step t to the wide window's frames)."""
    pad = graph_pad(window_len)
    if ref_len != window_len + 2 * pad:
        raise ConfigError(f"graph: reference windows of {window_len}-frame queries must have "
                          f"{window_len + 2 * pad} frames, got {ref_len}")
    pivot = window_len // 2
    return path_dp(step, window_len, DEFAULT_FAN_OUT, pivot)[..., pad + pivot]


def graph_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Graph-matching path cost of matching windows: ``a [T, L, D]`` × ``b [T, L + 2·pad, D]`` → ``[T]``
    (as :func:`seqnet.matching.graph.graph_pairs` on the frames)."""
    return _graph_cost(lambda t: F.pairwise_distance(a[:, t, None], b, eps=PAIRWISE_EPS), a.shape[1], b.shape[1])


def cross_graph(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Path costs of every pair: ``[S, L, D]`` × ``[R, L + 2·pad, D]`` → ``[S, R]`` (each step's ``[S, R, L']``
    distances from one matrix product over the windows' frames)."""
    flat = r.reshape(-1, r.shape[-1])
    return _graph_cost(lambda t: pairwise_distances(q[:, t], flat).view(len(q), *r.shape[:2]), q.shape[1],
                       r.shape[1])


def triplet_loss(
    query: torch.Tensor, positive: torch.Tensor, negatives: torch.Tensor, anchor: torch.Tensor, margin: float,
    total: int | None = None, distance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] = pair_distance,
) -> TripletLoss:
    """Triplet margin loss of T triplets given as (query ``anchor[t]``, its positive, negative ``t``).

    Args:
        query: ``[B, D]`` query descriptors; positive: ``[B, D]`` one positive per query (or ``[B, L, D]``:
            windows of frame descriptors, with ``distance`` :func:`seqmatch_distance`).
        negatives: ``[T, D]`` (or ``[T, L, D]``) the negatives of all triplets.
        anchor: ``[T]`` long, the query (row of ``query``) of each negative.
        margin: hinge margin m > 0 on Euclidean distances.
        total: the number of triplets the mean is over (default T; distributed training: those of the
            whole batch, so that the losses of its shares sum to the batch's mean).
        distance: ``d(a, b)`` of matching rows (default Euclidean; :func:`seqmatch_distance` for windows).

    Returns:
        :class:`TripletLoss` with ``per_triplet`` of shape ``[T]``; ``loss = Σ_t max(0, d(q, p) − d(q, n_t) + m) / T``.
    """
    same = (positive.ndim == query.ndim and positive.shape[0] == query.shape[0]
            and positive.shape[-1] == query.shape[-1])  # windows: the reference's may be longer (vseqmatch)
    if query.ndim < 2 or not same:
        raise ConfigError(f"query and positive must both be [B, D] (or [B, L, D]), got {tuple(query.shape)} and "
                          f"{tuple(positive.shape)}")
    if negatives.shape[1:] != positive.shape[1:] or anchor.shape != negatives.shape[:1]:
        dims = ", ".join(map(str, positive.shape[1:]))
        raise ConfigError(f"negatives must be [T, {dims}] with anchor [T], got {tuple(negatives.shape)} "
                          f"and {tuple(anchor.shape)}")
    if not margin > 0:
        raise ConfigError(f"margin must be > 0, got {margin}")
    if total is not None and total < max(int(anchor.numel()), 1):
        raise ConfigError(f"total must be >= the {anchor.numel()} triplets given (and >= 1), got {total}")
    n = int(anchor.numel())
    denom = max(n, 1) if total is None else total
    if distance is pair_distance and query.ndim == 2:  # the paper's loss: one node, its gradient written out
        loss, hinge = triplet_hinge(query, positive, negatives, anchor, margin, denom, PAIRWISE_EPS)
        return TripletLoss(loss, n, int((hinge > 0).sum()), hinge)
    hinge = F.relu(distance(query, positive)[anchor] - distance(query[anchor], negatives) + margin)  # [T]
    return TripletLoss(hinge.sum() / denom, n, int((hinge > 0).sum()), hinge.detach())


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


Model = Callable[["torch.Tensor"], "torch.Tensor"]


def describe_windows_whole(model: Model, windows: torch.Tensor) -> torch.Tensor:
    """The triplet loss's descriptors: one per window, ``[B, L, D]`` → ``[B, D']``."""
    return model(windows)


def describe_windows_framewise(model: Model, windows: torch.Tensor) -> torch.Tensor:
    """The seqmatch loss's descriptors: S_1 of every frame, ``[B, L, D]`` → ``[B, L, D']``."""
    b, n, d = windows.shape
    y = model(windows.reshape(b * n, 1, d))
    return y.reshape(b, n, y.shape[-1])  # (an empty share of a distributed batch stays [0, L, D'])


def describe_pair(loss: WindowLoss, model: Model, q_windows: torch.Tensor,
                  r_windows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``loss.describe`` of query windows ``[B, L, D]`` and reference windows ``[N, L', D]`` in one forward pass
    (one DDP forward per step); ``L' > L`` (a framewise loss's widened reference): every frame as a window."""
    if q_windows.shape[1] == r_windows.shape[1]:
        emb = loss.describe(model, torch.cat([q_windows, r_windows]))
        return emb[: len(q_windows)], emb[len(q_windows) :]
    if not loss.framewise:
        raise ConfigError(f"windows of {q_windows.shape[1]} and {r_windows.shape[1]} frames need a framewise loss")
    (b, lq, d), (n, lr, _) = q_windows.shape, r_windows.shape
    y = model(torch.cat([q_windows.reshape(b * lq, 1, d), r_windows.reshape(n * lr, 1, d)]))
    return y[: b * lq].reshape(b, lq, -1), y[b * lq :].reshape(n, lr, -1)


def cross_seqmatch(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """SeqMatch scores of every pair of windows: ``[S, L, D]`` × ``[R, L, D]`` → ``[S, R]``."""
    out = pairwise_distances(q[:, 0], r[:, 0])
    for t in range(1, q.shape[1]):
        out += pairwise_distances(q[:, t], r[:, t])
    return out


@dataclasses.dataclass(frozen=True)
class WindowLoss:
    """One entry of :data:`LOSSES`: how training windows are described and scored.

    Attributes:
        describe: ``(model, windows [B, L, D])`` → what is scored (``[B, D']`` or ``[B, L, D']``).
        pair: score of matching rows of two described batches → ``[T]`` (the loss's ``d``).
        cross: scores of every pair of two described batches → ``[S, R]`` (mining).
        framewise: whether ``describe`` keeps one descriptor per frame (the mining cache describes frames).
        help: one line for ``seqnet train --help``.
        val_method: the method the val split ranks with (at the training window's length; "": the
            model's own role, ``seqnet`` or ``s1``).
        ref_pad: frames each reference window is widened by on either side, from the window length
            (the velocity-robust loss's trajectories reach beyond it; 0 for the others).
    """

    describe: Callable[[Model, torch.Tensor], torch.Tensor]
    pair: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    cross: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    framewise: bool
    help: str
    val_method: str = ""
    ref_pad: Callable[[int], int] = lambda window_len: 0


LOSSES: dict[str, WindowLoss] = {
    "triplet": WindowLoss(describe_windows_whole, pair_distance, pairwise_distances, False,
                          "margin loss on the L2 distance of the windows' descriptors (the paper's; S_L or S_1)"),
    "seqmatch": WindowLoss(describe_windows_framewise, seqmatch_distance, cross_seqmatch, True,
                           "SeqMatchNet-style: margin loss on the SeqMatch score of --match-len-frame windows of "
                           "S_1 descriptors (S_1 only)", "s1+seqmatch"),
    "vseqmatch": WindowLoss(describe_windows_framewise, vseqmatch_distance, cross_vseqmatch, True,
                            "as seqmatch, on the velocity-robust SeqMatch score (min over the trajectories of "
                            "slopes 0.5-2; S_1 only)", "s1+vseqmatch", velocity_pad),
    "graph": WindowLoss(describe_windows_framewise, graph_distance, cross_graph, True,
                        "as seqmatch, on the graph matcher's path cost (cheapest path with steps 0-2 through the "
                        "window's centre, GISM-style; S_1 only)", "s1+graph", graph_pad),
}
