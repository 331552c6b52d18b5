"""Recall@K: the fraction of queries with a correct reference among the top K retrieved.

A retrieved reference is correct when it lies within the localisation radius of the query
(Euclidean distance between positions: metres for UTM, frames for Nordland). Queries without
any reference inside the radius are excluded from the denominator and counted.
"""

from __future__ import annotations

from typing import Sequence

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
    if len(r_pos) == 0:
        return np.zeros(len(q_pos), dtype=bool)
    dist, _ = cKDTree(r_pos).query(q_pos, k=1)
    return np.asarray(dist) <= radius


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
    if any(int(k) < 1 for k in ks):
        raise ConfigError(f"every K must be >= 1, got {list(ks)}")
    retrieved = np.asarray(retrieved, dtype=np.int64).reshape(len(q_pos), -1)
    pos = has_positive(q_pos, r_pos, radius)
    cum = np.logical_or.accumulate(hits(retrieved, q_pos, r_pos, radius), axis=1) if retrieved.shape[1] else None
    out: dict[str, float | int] = {}
    n = int(pos.sum())
    for k in ks:
        if cum is None or n == 0:
            out[f"recall@{k}"] = float("nan")
            continue
        col = min(int(k), cum.shape[1]) - 1
        out[f"recall@{k}"] = float(cum[pos, col].mean())
    out["queries"] = n
    out["no_positive"] = int(len(pos) - n)
    return out


def recall_curve(
    retrieved: np.ndarray, q_pos: np.ndarray, r_pos: np.ndarray, radius: float, k_max: int = 20
) -> np.ndarray:
    """Recall@K for K = 1..k_max as a ``[k_max]`` array (for plots)."""
    res = recall_at_k(retrieved, q_pos, r_pos, radius, ks=range(1, k_max + 1))
    return np.array([res[f"recall@{k}"] for k in range(1, k_max + 1)])
