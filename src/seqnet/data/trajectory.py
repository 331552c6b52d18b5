"""A localised track as drawn: :class:`TrackView`, the arrays the trajectory plot reads (built by the localiser
and by the report from an evaluation; drawn by :mod:`seqnet.report.trajectory`)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class TrackView:
    """A track as drawn: the reference route ``ref [Nr, P]``, each frame's estimate ``estimate [Nq, P]`` (the
    position of its best reference item; NaN without an answer), its true position ``truth [Nq, P]`` (None without
    ground truth; NaN outside it), ``correct`` / ``has_positive [Nq]`` (None without), ``confidence [Nq]``, the
    positions' ``unit`` and the ``radius``."""

    ref: np.ndarray
    estimate: np.ndarray
    truth: np.ndarray | None
    correct: np.ndarray | None
    has_positive: np.ndarray | None
    confidence: np.ndarray
    unit: str | None
    radius: float

    @classmethod
    def of(cls, ref: np.ndarray, r_pos: np.ndarray, best: np.ndarray, confidence: np.ndarray,
           truth: np.ndarray | None, correct: np.ndarray | None, has: np.ndarray | None, unit: str | None,
           radius: float) -> TrackView:
        """The view of the answers ``best [Nq]`` (indices into reference items at ``r_pos [Nr', P]``; -1: none)
        on the route ``ref``."""
        return cls(np.asarray(ref, np.float64).reshape(len(ref), -1), answer_positions(r_pos, best), truth, correct,
                   has, np.asarray(confidence, np.float64), unit, float(radius))


def answer_positions(r_pos: np.ndarray, best: np.ndarray) -> np.ndarray:
    """``[N, P]`` float64: the position of each answer ``best [N]`` (indices into reference items at
    ``r_pos [R, P]``); NaN for no answer (-1), and ``[N, 1]`` NaN when there is no reference item."""
    best = np.asarray(best, np.int64)
    if not len(r_pos):
        return np.full((len(best), 1), np.nan)
    pos = np.asarray(r_pos, np.float64).reshape(len(r_pos), -1)
    return np.where((best >= 0)[:, None], pos[np.maximum(best, 0)], np.nan)
