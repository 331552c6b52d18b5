"""What Recall@K is given that says the user meant something else: ranked indices that are no integers
(:func:`integral`: distances passed as indices), positions transposed or not finite (:func:`positions_array`),
ground truth that makes Recall@K near-trivial (:func:`trivial_truth`: said by ``seqnet eval`` through
:func:`seqnet.methods.route.route_warnings`, and by :func:`seqnet.metrics.recall.recall_at_k`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.tensors import spread
from ..data.spacing import DEGREES_HINT, looks_like_degrees

TRIVIAL_SHARE = 0.5  # a query whose correct references are this share of the map or more: R@K says little


def trivial_truth(truth: Any, samples: int = 200) -> str | None:
    """Why the ground truth makes Recall@K near-trivial (the median query, of ``samples`` evenly spaced, has at
    least :data:`TRIVIAL_SHARE` of the references correct: constant positions, positions in degrees, or a radius
    as large as the route), None otherwise."""
    n_q, n_r = len(truth.q_pos), len(truth.r_pos)
    if n_q == 0 or n_r < 4:
        return None
    counts = [len(truth.of(int(i))) for i in spread(n_q, samples)]  # the ground truth's own test
    share = float(np.median(counts)) / n_r
    if share < TRIVIAL_SHARE:
        return None
    what = "positives" if truth.positives is not None else f"references within the radius {truth.radius:g}"
    hint = (f"({DEGREES_HINT})" if truth.positives is None and looks_like_degrees(np.concatenate(
        [truth.q_pos, truth.r_pos])) else "(constant positions, or a radius as large as the route? check the "
            "positions and the radius, and their unit)")
    return (f"the median query has {share:.0%} of the {n_r} references as its {what}: any answer is likely correct "
            f"and Recall@K says little {hint}")


KNN_HINT = "hint: knn returns (scores, indices): unpack it as scores, idx = knn(...) and pass idx"


def k_values(ks: Any) -> list[int]:
    """The K values of Recall@K: a sequence of integers >= 1, or one integer K (``ks=5``: ``[5]``); anything
    else (a bool, a string, a float K, K < 1, none at all) is a :class:`ConfigError`."""
    def whole(k: Any) -> bool:
        return isinstance(k, (int, np.integer)) and not isinstance(k, (bool, np.bool_)) and k >= 1

    many = isinstance(ks, (Sequence, np.ndarray)) and not isinstance(ks, (str, bytes))
    given = [ks] if whole(ks) else ks if many else ()
    if not len(given) or not all(whole(k) for k in given):
        raise ConfigError(f"every K must be an integer >= 1: ks is one K or a sequence of them (e.g. ks=(1, 5, 10)), "
                          f"got {ks!r}")
    return [int(k) for k in given]


def retrieved_array(retrieved: Any) -> np.ndarray:
    """``retrieved`` as a numpy array; rows of different lengths (a ragged list) are a :class:`ConfigError`."""
    try:
        return np.asarray(retrieved)
    except ValueError as err:  # numpy refuses ragged nested sequences
        lens = sorted({len(r) for r in retrieved if hasattr(r, "__len__")}) if hasattr(retrieved, "__iter__") else []
        raise ConfigError(f"retrieved must be [M, K] (K reference indices in every row), got rows of lengths "
                          f"{', '.join(map(str, lens[:5]))}{', ...' if len(lens) > 5 else ''} (hint: pad the short "
                          "rows with -1, which means none)") from err


def integral(retrieved: np.ndarray) -> np.ndarray:
    """Ranked reference indices ``[M, K]`` given as another dtype: whole floats are taken, anything else (distances
    passed as indices, e.g. knn's ``(scores, indices)`` unpacked the other way round, or booleans: a hit matrix) is
    a :class:`ConfigError`.

    Whole floats that repeat a value >= 0 within a row are refused too: a ranking never retrieves a reference
    twice, so such a row holds scores (inner products of binary descriptors are whole numbers, and tie). The
    rule cannot refuse a correct ranking (only -1, "none", may repeat); whole-number scores without a tie in
    any row (e.g. K = 1) cannot be told from indices."""
    if retrieved.dtype == bool:  # read as indices 0 / 1 it gave R@1 near 0 with no error
        raise ConfigError(f"retrieved holds booleans ({retrieved.shape[0]} x {retrieved.shape[1]}), not reference "
                          f"indices: a hit or ground-truth matrix passed as the ranking? ({KNN_HINT})")
    if retrieved.dtype.kind != "f":
        raise ConfigError(f"retrieved must hold reference indices (integers), got dtype {retrieved.dtype}")
    bad = retrieved[~(np.isfinite(retrieved) & (retrieved == np.round(retrieved)))]
    if bad.size:
        shown = ", ".join(f"{v:.4g}" for v in bad[:3])
        raise ConfigError(f"retrieved holds non-integers ({shown}{', ...' if bad.size > 3 else ''}), not reference "
                          f"indices: distances passed as indices? ({KNN_HINT})")
    _no_repeats(retrieved)
    return retrieved


def _no_repeats(retrieved: np.ndarray) -> None:
    """A :class:`ConfigError` naming the first row of whole floats ``[M, K]`` that repeats a value >= 0."""
    srt = np.sort(retrieved, axis=1)
    rep = (srt[:, 1:] == srt[:, :-1]) & (srt[:, 1:] >= 0)
    if rep.any():
        row = int(np.flatnonzero(rep.any(axis=1))[0])
        shown = ", ".join(f"{v:g}" for v in retrieved[row, :5])
        raise ConfigError(f"retrieved row {row} ({shown}{', ...' if retrieved.shape[1] > 5 else ''}) repeats a "
                          f"value, but a ranking never retrieves a reference twice: whole-number scores passed as "
                          f"indices? ({KNN_HINT})")


def positions_array(p: np.ndarray, side: str) -> np.ndarray:
    """``p`` as float64 ``[N, P]`` (a 1-D array: ``[N, 1]``); a transposed array or NaN / inf is a
    :class:`ConfigError`."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 1:
        p = p[:, None]
    if p.ndim != 2:
        raise ConfigError(f"{side} positions must be [N, P], got shape {p.shape}")
    if p.shape[1] > 3 >= p.shape[0]:
        raise ConfigError(f"{side} positions look transposed: shape {p.shape}, but positions are [N, P] (one row per "
                          f"image, P = 1 frame number or 2 coordinates); hint: pass them transposed ([{p.shape[1]}, "
                          f"{p.shape[0]}], e.g. pos.T)")
    if not np.isfinite(p).all():
        row = int(np.flatnonzero(~np.isfinite(p).all(axis=1))[0])
        raise ConfigError(f"{side} positions hold NaN or inf (first at row {row}); hint: drop those rows (and their "
                          "descriptors), or give them positions")
    return p
