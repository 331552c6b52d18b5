"""Recall@K: the fraction of queries with a correct reference among the top K retrieved.

A retrieved reference is correct when it lies within the localisation radius of the query
(Euclidean distance between positions, inclusive: ``distance <= radius``; metres for UTM, frames
for Nordland), or, when the dataset gives explicit positives, when it is one of the query's
positives (:class:`GroundTruth`). The denominator (:data:`RECALL_DENOMINATORS`): ``positives``
(default, as the original SeqNet code): queries without any correct reference are excluded and
counted (``no_positive``); ``all`` (as VPR-methods-evaluation and most current papers): every
evaluated query counts, those without a correct reference as failures.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...core.errors import ConfigError
from ...core.log import logger
from ..inputs import k_values, trivial_truth
from .truth import GroundTruth, check_radius, ground_truth, has_positive, hits, near_pairs

__all__ = ["DEFAULT_KS", "RECALL_DENOMINATORS", "VAL_MIN", "GroundTruth", "check_radius", "ground_truth",
           "has_positive", "hits", "near_pairs", "recall", "recall_at_k", "recall_curve", "retrieved_ks"]

DEFAULT_KS = (1, 5, 10, 20, 100)
VAL_MIN = 50  # val queries below which a choice by R@1 (an epoch, K, λ) is mostly noise: 1 query = 2% of R@1
RECALL_DENOMINATORS = {"positives": "queries with a correct reference (the others left out, counted)",
                       "all": "every evaluated query (those without a correct reference are failures)"}


def recall(retrieved: np.ndarray, truth: GroundTruth, ks: Sequence[int] | int = DEFAULT_KS,
           denominator: str = "positives") -> dict[str, float | int]:
    """Recall@K for each K in ``ks`` of the ranked reference items ``retrieved [M, K_max]`` (best first),
    over the queries with a correct reference (``denominator="positives"``) or over all M (``"all"``).

    Returns ``{"recall@K": value, ..., "queries": the denominator (the queries with a correct reference, or all M),
    "no_positive": the queries without one}`` (and ``"positive_not_indexed"``: the queries whose correct references
    are all frames of ``truth.matched`` outside the items, counted as failures, when there are any); recall is
    ``nan`` when no query has a correct reference. K larger than the list length uses the whole list (as the
    evaluation scores a reference of fewer than K items: every one retrieved); :func:`recall_at_k` refuses it
    otherwise.
    """
    ks = k_values(ks)
    if denominator not in RECALL_DENOMINATORS:
        raise ConfigError(f"recall denominator {denominator!r} is not one of {', '.join(RECALL_DENOMINATORS)}")
    retrieved = truth.check_retrieved(retrieved)
    pos = truth.has_positive()
    n = int(pos.sum())
    cum = None
    if n and retrieved.shape[1]:
        cum = np.logical_or.accumulate(truth.hits(retrieved), axis=1)
    out: dict[str, float | int] = {}
    for k in ks:
        if n == 0:  # no positive: nothing to recall ("all": every query is a failure)
            out[f"recall@{k}"] = 0.0 if denominator == "all" and len(pos) else float("nan")
        elif cum is None:  # nothing retrieved: no query is localised
            out[f"recall@{k}"] = 0.0
        else:
            found = cum[pos, min(int(k), cum.shape[1]) - 1]
            out[f"recall@{k}"] = float(found.mean() if denominator == "positives" else found.sum() / len(pos))
    out["queries"] = n if denominator == "positives" else int(len(pos))  # the denominator the user asked for
    out["no_positive"] = int(len(pos) - n)
    if truth.matched is not None and (unindexed := int((pos & ~truth.item_positive()).sum())):
        out["positive_not_indexed"] = unindexed  # counted, as failures: their correct references are no items
    return out


def recall_at_k(
    retrieved: np.ndarray,
    q_pos: np.ndarray,
    r_pos: np.ndarray,
    radius: float,
    ks: Sequence[int] | int | None = None,
) -> dict[str, float | int]:
    """Recall@K with the radius ground truth (see :func:`recall`).

    Args:
        retrieved: ``[M, K_max]`` ranked indices into ``r_pos`` (best first).
        q_pos: ``[M, P]`` query positions; r_pos: ``[R, P]`` reference positions.
        radius: localisation radius (same unit as positions; inclusive).
        ks: the K values (one integer: that K alone); None: :data:`DEFAULT_KS` up to the ``K_max`` retrieved.

    A K above ``K_max`` is undefined unless every reference was retrieved (``K_max >= R``): a given one is a
    :class:`ConfigError`, a default one is left out with a WARNING line (:func:`retrieved_ks`). A WARNING line
    when the ground truth makes Recall@K near-trivial (the median query has half the references within the
    radius: positions in degrees or kilometres with a radius in metres, constant positions), as ``seqnet eval``
    says (:func:`seqnet.metrics.inputs.trivial_truth`).
    """
    truth = GroundTruth(q_pos, r_pos, radius)
    out = recall(retrieved, truth, retrieved_ks(ks, truth.check_retrieved(retrieved).shape[1], len(truth.r_pos)))
    line = trivial_truth(truth)
    if line:
        logger.warning("recall_at_k: %s", line)
    return out


def retrieved_ks(ks: Sequence[int] | int | None, width: int, n_refs: int) -> list[int]:
    """The K values :func:`recall_at_k` can score from ``width`` columns retrieved of ``n_refs`` references: a K
    above ``width`` counts only what was retrieved (R@100 from 5 columns is R@5), so it is refused when given,
    and left out with a WARNING when ``ks`` is None (:data:`DEFAULT_KS`); every K is defined when every
    reference was retrieved (``width >= n_refs``) or none was (``width`` 0: nothing found)."""
    given = k_values(DEFAULT_KS if ks is None else ks)
    over = [k for k in given if width < min(k, n_refs) and width > 0]
    if not over:
        return given
    fix = f"retrieve more (knn(..., k={max(over)})) or pass ks= up to {width}"
    if ks is not None:
        raise ConfigError(f"recall_at_k: K {', '.join(map(str, over))} above the {width} columns retrieved (of "
                          f"{n_refs} references) would count only those {width}; {fix}")
    logger.warning("recall_at_k: R@%s left out: the %d columns retrieved (of %d references) cannot score them; %s",
                   ", R@".join(map(str, over)), width, n_refs, fix)
    return [k for k in given if k not in over]


def recall_curve(retrieved: np.ndarray, truth: GroundTruth, k_max: int = 20) -> np.ndarray:
    """Recall@K for K = 1..k_max as a ``[k_max]`` array (for plots)."""
    res = recall(retrieved, truth, ks=range(1, k_max + 1))
    return np.array([res[f"recall@{k}"] for k in range(1, k_max + 1)])
