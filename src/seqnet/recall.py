"""Recall@K: the fraction of queries with a correct reference among the top K retrieved.

A retrieved reference is correct when it lies within the localisation radius of the query
(Euclidean distance between positions: metres for UTM, frames for Nordland). Queries without
any reference inside the radius are excluded from the denominator and counted.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from .errors import ConfigError

DEFAULT_KS = (1, 5, 10, 20, 100)


def check_radius(radius: float) -> float:
    """Validate a localisation radius (a finite number > 0)."""
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise ConfigError(f"radius must be a number, got {radius!r}") from None
    if not np.isfinite(r) or r <= 0:
        raise ConfigError(f"radius must be a finite number > 0, got {radius!r}")
    return r


def has_positive(q_pos: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """``[M]`` bool: whether any reference position ``r_pos [R, P]`` lies within ``radius``."""
    if len(r_pos) == 0 or len(q_pos) == 0:
        return np.zeros(len(q_pos), dtype=bool)
    _, nearest = cKDTree(r_pos).query(q_pos, k=1)
    # the same distance formula as :func:`hits`, so "has a positive" and "is a hit" agree exactly
    return np.linalg.norm(r_pos[nearest] - q_pos, axis=-1) <= radius


def hits(retrieved: np.ndarray, q_pos: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """``[M, K]`` bool: whether ``retrieved[m, k]`` (a row of ``r_pos``; -1 = none) is a true match."""
    valid = retrieved >= 0
    d = np.linalg.norm(r_pos[np.where(valid, retrieved, 0)] - q_pos[:, None, :], axis=-1)
    return (d <= radius) & valid


def recall_at_k(
    retrieved: np.ndarray,
    q_pos: np.ndarray,
    r_pos: np.ndarray,
    radius: float,
    ks: Sequence[int] = DEFAULT_KS,
) -> dict[str, float | int]:
    """Recall@K for each K in ``ks``.

    Args:
        retrieved: ``[M, K_max]`` ranked indices into ``r_pos`` (best first).
        q_pos: ``[M, P]`` query positions; r_pos: ``[R, P]`` reference positions.
        radius: localisation radius (same unit as positions).
        ks: the K values. K larger than the list length uses the whole list.

    Returns:
        ``{"recall@K": value, ..., "queries": n_evaluated, "no_positive": n_excluded}``.
        Recall is ``nan`` when no query has a positive.
    """
    radius = check_radius(radius)
    ks = list(ks)
    if not ks or any(int(k) < 1 for k in ks):
        raise ConfigError(f"every K must be >= 1 (and at least one K given), got {ks}")
    q_pos, r_pos = _positions(q_pos, "query"), _positions(r_pos, "reference")
    if q_pos.shape[1] != r_pos.shape[1]:
        raise ConfigError(f"query positions are {q_pos.shape[1]}-D but reference positions {r_pos.shape[1]}-D")
    retrieved = np.asarray(retrieved)
    if retrieved.ndim == 1:
        retrieved = retrieved[:, None]
    if retrieved.ndim != 2 or retrieved.shape[0] != len(q_pos):
        raise ConfigError(f"retrieved must be [{len(q_pos)}, K] (one row per query), got shape {retrieved.shape}")
    retrieved = retrieved.astype(np.int64, copy=False)
    if retrieved.size and (retrieved.min() < -1 or retrieved.max() >= len(r_pos)):
        raise ConfigError(f"retrieved indices must lie in 0..{len(r_pos) - 1} (or -1 for none)")
    pos = has_positive(q_pos, r_pos, radius)
    n = int(pos.sum())
    cum = None
    if n and retrieved.shape[1]:
        cum = np.logical_or.accumulate(hits(retrieved, q_pos, r_pos, radius), axis=1)
    out: dict[str, float | int] = {}
    for k in ks:
        if n == 0:
            out[f"recall@{k}"] = float("nan")
        elif cum is None:  # nothing retrieved: no query is localised
            out[f"recall@{k}"] = 0.0
        else:
            out[f"recall@{k}"] = float(cum[pos, min(int(k), cum.shape[1]) - 1].mean())
    out["queries"] = n
    out["no_positive"] = int(len(pos) - n)
    return out


def _positions(p: np.ndarray, side: str) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 1:
        p = p[:, None]
    if p.ndim != 2:
        raise ConfigError(f"{side} positions must be [N, P], got shape {p.shape}")
    return p


def recall_curve(
    retrieved: np.ndarray, q_pos: np.ndarray, r_pos: np.ndarray, radius: float, k_max: int = 20
) -> np.ndarray:
    """Recall@K for K = 1..k_max as a ``[k_max]`` array (for plots)."""
    res = recall_at_k(retrieved, q_pos, r_pos, radius, ks=range(1, k_max + 1))
    return np.array([res[f"recall@{k}"] for k in range(1, k_max + 1)])
