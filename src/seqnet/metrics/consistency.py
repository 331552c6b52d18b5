"""Sequence confidence: a top-1 is trusted more when the neighbouring queries' top-1s agree with it.

The ratio confidence (:func:`seqnet.metrics.precision_recall.ratio_confidence`) looks at one query's scores.
Along a route, a correct answer has a second witness: the queries just before and after it are answered with the
references just before and after it, the query and the map moving together; a wrong answer (a look-alike place)
is usually alone. The *sequence confidence* of query ``i`` counts its neighbours ``j`` (query frames within
``span`` of it, in its own query sequence; the ``span`` before it only, when ``causal``) whose top-1 reference
``t_j`` agrees:

    | (t_j − t_i) − v · (q_j − q_i) |  ≤  max(1, |v|)          (reference frames)

where ``v`` is the step of the map per query frame (1 at equal sampling, −1 on a route driven the other way): the
one on which the most pairs of neighbouring answers agree, in each query sequence (:func:`sequence_steps`,
:func:`map_step`; a wrong answer agrees with nothing in particular, so even a majority of wrong answers leaves it
where the right ones put it), and the tolerance is one query step (one reference frame when the map is sparser
than the queries). A sequence whose answers stand still (``|v| · span < 1``: a matcher stuck on one reference,
or a map far sparser than the queries) has no neighbour counted: its confidence is the ratio's, scaled. Then

    confidence = (agreeing neighbours + ratio confidence) / (neighbours possible + 1)   in [0, 1]

so the count decides and the ratio breaks ties. It assumes what SeqMatch assumes, a steady relative speed, here
over each query sequence (stops or speed changes within one weaken it); reference frames are numbered in the
map's recorded order.
"""

from __future__ import annotations

import dataclasses

import numpy as np

CONFIDENCES = ("ratio", "sequence")  # what a confidence is: one query's scores, or also its neighbours' answers


@dataclasses.dataclass(frozen=True)
class QueryOrder:
    """Where the evaluated items lie in their traverses, for :func:`sequence_confidence`.

    Attributes:
        q_frames: ``[M]`` query frame of each evaluated query; q_seq: ``[M]`` its query sequence (any id: the
            first frame of its sequence), None: one sequence.
        r_frames: ``[R]`` reference frame of each indexed reference (what the top-1 indices point into).
        span: neighbours within this many query frames (the window length L).
        causal: only the ``span`` queries before (an online localiser's view), else both sides.
    """

    q_frames: np.ndarray
    r_frames: np.ndarray
    span: int
    causal: bool = False
    q_seq: np.ndarray | None = None

    @property
    def offsets(self) -> np.ndarray:
        """The query-frame offsets of the neighbours looked at."""
        before = np.arange(-self.span, 0)
        return before if self.causal else np.r_[before, np.arange(1, self.span + 1)]


def sequence_confidence(ratio: np.ndarray, top: np.ndarray, order: QueryOrder) -> np.ndarray:
    """``[M]`` sequence confidence (module docstring) of the queries whose ratio confidence is ``ratio [M]`` and
    whose top-1 is ``top [M]`` (indices into ``order.r_frames``; −1: no answer, which agrees with nothing)."""
    ratio = np.asarray(ratio, dtype=np.float64)
    q = np.asarray(order.q_frames, dtype=np.int64)
    m = len(q)
    seq = np.zeros(m, np.int64) if order.q_seq is None else np.asarray(order.q_seq, dtype=np.int64)
    top = np.asarray(top, dtype=np.int64)
    answered = top >= 0
    t = np.where(answered, np.asarray(order.r_frames, dtype=np.int64)[top.clip(0)], 0) if m else top
    offsets = order.offsets
    agree = np.zeros(m)
    if m:
        _, rank = np.unique(seq, return_inverse=True)  # sequences numbered 0…S−1
        width = int(q.max() - min(q.min(), 0)) + 2 * order.span + 2  # frames (and their neighbours) per sequence
        key = rank * width + (q - min(q.min(), 0) + order.span)  # one integer per (sequence, frame), sortable
        by = np.argsort(key, kind="stable")
        step = sequence_steps(q[by], t[by], rank[by], answered[by], order.span)[rank]  # [M] each query's step
        tol = np.maximum(1.0, np.abs(step))
        moving = np.abs(step) * order.span >= 1.0  # answers that stand still carry no evidence: not counted
        for d in offsets:
            pos = np.searchsorted(key[by], key + d).clip(0, m - 1)
            j = by[pos]  # the neighbour d frames away, when it was evaluated
            ok = (key[j] == key + d) & answered & answered[j] & moving
            agree += ok & (np.abs((t[j] - t) - step * d) <= tol)
    return np.clip((agree + ratio) / (len(offsets) + 1), 0.0, 1.0)


STEPS = np.round(np.arange(-4.0, 4.0001, 0.05), 2)  # the map steps per query frame considered (reference frames)


def sequence_steps(q: np.ndarray, t: np.ndarray, seq: np.ndarray, answered: np.ndarray, span: int) -> np.ndarray:
    """``[S]`` the map's step per query frame of each query sequence ``0…S−1`` (:func:`map_step` of its own
    answers; the step of all sequences together for one with fewer than ``2 span`` pairs of answers). Inputs as
    :func:`map_step`'s, ``seq`` numbered ``0…S−1``."""
    n_seq = int(seq.max()) + 1 if len(seq) else 0
    dt, dq, of = _pairs(q, t, seq, answered, span)  # every sequence's pairs, found once
    steps = np.full(n_seq, _voted_step(dt, dq))
    if n_seq > 1:
        for s in np.flatnonzero(np.bincount(of, minlength=n_seq) >= 2 * span):
            mine = of == s
            steps[s] = _voted_step(dt[mine], dq[mine])
    return steps


def map_step(q: np.ndarray, t: np.ndarray, seq: np.ndarray, answered: np.ndarray, span: int) -> float:
    """The map's step per query frame that the most answers agree on, from the pairs of answered queries ``span``
    frames apart or fewer in one sequence (``q``, ``t``, ``seq``, ``answered``: sorted by sequence, then frame):
    the step ``v0`` of :data:`STEPS` with the most pairs ``|(t_j − t_i) − v0 (q_j − q_i)| ≤ 1`` (ties: nearest
    1), refined to the median slope ``(t_j − t_i) / (q_j − q_i)`` of the pairs within ``max(1, |v0|)`` of it;
    1 when there is no pair."""
    return _voted_step(*_pairs(q, t, seq, answered, span)[:2])


def _voted_step(dt: np.ndarray, dq: np.ndarray) -> float:
    """:func:`map_step` of the pairs' ``dt = t_j − t_i`` and ``dq = q_j − q_i``."""
    if not len(dt):
        return 1.0
    votes = np.zeros(len(STEPS))
    for b in range(0, len(dt), 4096):  # [4096, len(STEPS)] at a time: memory bounded
        votes += (np.abs(dt[b:b + 4096, None] - STEPS[None] * dq[b:b + 4096, None]) <= 1.0).sum(axis=0)
    best = np.flatnonzero(votes == votes.max())
    v0 = float(STEPS[best[np.argmin(np.abs(STEPS[best] - 1.0))]])
    near = np.abs(dt - v0 * dq) <= max(1.0, abs(v0))
    return float(np.median(dt[near] / dq[near])) if near.any() else v0


def _pairs(q: np.ndarray, t: np.ndarray, seq: np.ndarray, answered: np.ndarray,
           span: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_j − t_i, q_j − q_i, sequence)`` of the answered pairs ``0 < q_j − q_i ≤ span`` of one sequence
    (sorted input)."""
    dts, dqs, seqs = [], [], []
    for lag in range(1, min(span, len(q) - 1) + 1):  # items ``lag`` apart in the sorted order
        dq = q[lag:] - q[:-lag]
        pair = (seq[lag:] == seq[:-lag]) & answered[lag:] & answered[:-lag] & (dq > 0) & (dq <= span)
        dts.append((t[lag:] - t[:-lag])[pair])
        dqs.append(dq[pair])
        seqs.append(seq[lag:][pair])
    if not dts:
        return np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    return (np.concatenate(dts).astype(np.float64), np.concatenate(dqs).astype(np.float64),
            np.concatenate(seqs).astype(np.int64))
