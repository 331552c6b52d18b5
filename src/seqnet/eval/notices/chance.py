"""Every method's Recall@K at the level of a random ranking: reference and query descriptors that do not compare
(different describers or settings, a PCA fitted on each traverse separately: same D, so nothing else refuses them),
or ground truth that does not belong to the images. A random ranking of R references finds a query with c correct
ones among its top K with probability ``1 - C(R - c, K) / C(R, K)``; the line is said when every method's R@K, at
every K below the references it indexes, is within a few standard errors of that expectation over its scored
queries."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..evaluation import Evaluation, ItemView

CHANCE_Z = 3.0  # R@K within this many standard errors of a random ranking's, and twice it (plus one query): at chance
CHANCE_MIN_QUERIES = 50  # fewer scored queries than this: a random ranking cannot be told from a poor method
CHANCE_BELOW = 0.05  # ... nor when a random ranking's R@K at the smallest K is this or more (few references)


def positive_counts(view: ItemView) -> np.ndarray:
    """``[M]`` int64: how many of the method's indexed references are correct for each query item (1-D positions:
    sorted neighbours, no scipy, as plain eval needs none)."""
    t = view.truth
    if t.positives is not None:
        return np.asarray(t.positives.counts(), dtype=np.int64)
    if t.r_pos.shape[1] == 1:
        srt = np.sort(np.asarray(t.r_pos[:, 0], np.float64))
        q = np.asarray(t.q_pos[:, 0], np.float64)
        return (np.searchsorted(srt, q + t.radius, side="right") - np.searchsorted(srt, q - t.radius)).astype(np.int64)
    q, _ = t.pairs()
    return np.bincount(q, minlength=len(t.q_pos)).astype(np.int64)


def random_recall(counts: np.ndarray, n_refs: int, k: int) -> np.ndarray:
    """``[M]``: the probability that a random ranking of ``n_refs`` references puts one of a query's ``counts [M]``
    correct references among its top ``k``: ``1 - C(R - c, K) / C(R, K)`` (1 when ``R - c < K``)."""
    c = np.clip(np.asarray(counts, dtype=np.int64), 0, n_refs)
    if k >= n_refs:
        return (c > 0).astype(np.float64)
    logf = np.concatenate([[0.0], np.cumsum(np.log(np.arange(1, n_refs + 1)))])  # log n!
    left = n_refs - c
    ok = left >= k
    lm = np.where(ok, left, k)
    miss = np.exp(logf[lm] - logf[lm - k] - logf[n_refs] + logf[n_refs - k])  # C(R-c, K) / C(R, K)
    return np.where(ok, 1.0 - miss, 1.0)


def at_chance(observed: float, expected: float, n: int) -> bool:
    """Whether an R@K ``observed`` over ``n`` queries is no higher than a random ranking's ``expected`` allows: within
    :data:`CHANCE_Z` standard errors of it and at most twice it, plus one query."""
    spread = CHANCE_Z * np.sqrt(expected * (1 - expected) / n)
    return observed <= min(expected + spread, 2 * expected) + 1.0 / n


def chance_figures(ev: Evaluation, ks: tuple[int, ...]) -> dict[str, list[tuple[int, float, float]]] | None:
    """Each method's ``(K, R@K, a random ranking's R@K)`` at the Ks of ``ks`` below its references, when every one
    is at chance (:func:`at_chance`) over at least :data:`CHANCE_MIN_QUERIES` queries and its smallest K tells a
    random ranking from a real one (a random R@K below :data:`CHANCE_BELOW`); None otherwise."""
    methods: Mapping[str, Any] = ev.results.get("methods") or {}
    every = ev.results.get("config", {}).get("recall_denominator") == "all"
    out: dict[str, list[tuple[int, float, float]]] = {}
    for name in ev.retrieved:
        entry, view = methods.get(name) or {}, ev.view(name)
        counts = positive_counts(view)
        scored = counts if every else counts[counts > 0]
        n_refs = len(view.r_items)
        if len(scored) < CHANCE_MIN_QUERIES or n_refs == 0:
            return None
        rows = [(k, float(entry[f"recall@{k}"]), float(random_recall(scored, n_refs, k).mean()))
                for k in ks if k < n_refs and isinstance(entry.get(f"recall@{k}"), float)]
        if not rows or rows[0][2] >= CHANCE_BELOW or not all(at_chance(r, e, len(scored)) for _, r, e in rows):
            return None
        out[name] = rows
    return out or None


def chance_notice(ev: Evaluation, ks: tuple[int, ...]) -> str | None:
    """The line when every method's R@K (at ``ks``) is what a random ranking gives (:func:`chance_figures`),
    naming the descriptors' provenance when neither side records one (nothing checked they were made alike)."""
    figures = chance_figures(ev, ks)
    if figures is None:
        return None
    name, rows = next(iter(figures.items()))
    view = ev.view(name)
    counts = positive_counts(view)
    said = ", ".join(f"R@{k} {r:.3f} against {e:.3f}" for k, r, e in (rows[0], rows[-1]))
    ds = ev.dataset
    provs = [getattr(getattr(ds, side, None), "provenance", None) for side in ("reference", "query")]
    if ds is not None and not any(provs):
        why = ("; neither descriptor file records how it was made (no provenance: only D was checked, so nothing "
               "held them to one describer)")
    elif ds is not None and all(provs) and provs[0].get("id") == provs[1].get("id"):
        why = "; their provenance is one, so the ground truth may rather not belong to these images"
    else:
        why = ""
    return (f"every method's R@K is what a random ranking gives ({name}: {said} by chance, from "
            f"{float(counts[counts > 0].mean()) if (counts > 0).any() else 0:.1f} correct references per query among "
            f"{len(view.r_items)}; {len(figures)} method{'s' if len(figures) > 1 else ''} alike): the reference and "
            f"query descriptors may not be comparable (different describers or settings, PCAs fitted on each "
            f"traverse separately){why}; hint: describe both traverses with one describer and one fitted state (fit "
            "any PCA on both traverses at once), and check that the positions belong to these images")
