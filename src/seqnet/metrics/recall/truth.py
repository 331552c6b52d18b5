"""What is correct for each query: the radius (Euclidean distance between positions, inclusive) or explicit
positives (:class:`GroundTruth`, :func:`ground_truth`, the one ground truth of evaluation, maps and the localiser)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np

from ...core.errors import ConfigError
from ...data.positives import Positives
from ..inputs import integral, positions_array, retrieved_array


def check_radius(radius: float) -> float:
    """Validate a localisation radius (a finite number > 0)."""
    try:
        r = float(radius)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"radius must be a number, got {radius!r}") from err
    if not np.isfinite(r) or r <= 0:
        raise ConfigError(f"radius must be a finite number > 0, got {radius!r}")
    return r


def has_positive(q_pos: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """``[M]`` bool: whether any reference position ``r_pos [R, P]`` lies within ``radius``."""
    if len(r_pos) == 0 or len(q_pos) == 0:
        return np.zeros(len(q_pos), dtype=bool)
    if r_pos.shape[1] == 1:  # positions along a route: the nearest is a neighbour in sorted order (no scipy)
        return _has_positive_1d(q_pos, r_pos, radius)
    from scipy.spatial import cKDTree  # scipy loads on first use: `seqnet --help` imports this module

    _, nearest = cKDTree(r_pos).query(q_pos, k=1)
    # the same distance formula as :func:`hits`, so "has a positive" and "is a hit" agree exactly
    return np.linalg.norm(r_pos[nearest] - q_pos, axis=-1) <= radius


def _has_positive_1d(q_pos: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """:func:`has_positive` of 1-D positions ``[M, 1]``, ``[R, 1]``: the two sorted neighbours of each query,
    their distances by :func:`hits`' formula."""
    srt = np.sort(r_pos[:, 0])
    j = np.searchsorted(srt, q_pos[:, 0])
    near = [srt[np.clip(j - 1, 0, len(srt) - 1)], srt[np.clip(j, 0, len(srt) - 1)]]
    return np.any([np.linalg.norm(n[:, None] - q_pos, axis=-1) <= radius for n in near], axis=0)


def hits(retrieved: np.ndarray, q_pos: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """``[M, K]`` bool: whether ``retrieved[m, k]`` (a row of ``r_pos``; -1 = none) is a true match."""
    valid = retrieved >= 0
    d = np.linalg.norm(r_pos[np.where(valid, retrieved, 0)] - q_pos[:, None, :], axis=-1)
    return (d <= radius) & valid


def near_pairs(rows: np.ndarray, refs: np.ndarray, r_pos: np.ndarray, radius: float,
               block: int = 2**24) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Blocks of ``(row [n], reference [n])`` pairs: for each pair ``(rows[i], refs[i])``, every reference within
    ``radius`` of reference ``refs[i]`` (distances between the reference positions ``r_pos [R, P]`` only),
    itself included. One k-d tree query per distinct reference (O(pairs x neighbours), not O(pairs x R)), in
    float64 about the first position (UTM coordinates lose metres in float32); each block holds at most
    ``block`` pairs (at least one input pair's)."""
    from scipy.spatial import cKDTree

    rows, refs = np.asarray(rows, dtype=np.int64), np.asarray(refs, dtype=np.int64)
    if rows.size == 0:
        return
    pts = np.asarray(r_pos, dtype=np.float64).reshape(len(r_pos), -1)
    pts = pts - pts[:1]
    uniq, inv = np.unique(refs, return_inverse=True)
    balls = cKDTree(pts).query_ball_point(pts[uniq], radius)
    lens = np.fromiter((len(x) for x in balls), dtype=np.int64, count=len(balls))
    flat, starts = np.concatenate([np.asarray(x, dtype=np.int64) for x in balls]), np.cumsum(lens) - lens
    cnt = lens[inv]  # neighbours of each pair's reference
    ends = np.cumsum(cnt)
    s = 0
    while s < len(rows):
        e = max(s + 1, int(np.searchsorted(ends, ends[s] - cnt[s] + block, side="right")))
        c = cnt[s:e]
        yield np.repeat(rows[s:e], c), flat[np.repeat(starts[inv[s:e]] - (np.cumsum(c) - c), c) + np.arange(c.sum())]
        s = e


@dataclasses.dataclass
class GroundTruth:
    """What is correct for each of M query items among R reference items.

    Attributes:
        q_pos: ``[M, P]`` query positions; r_pos: ``[R, P]`` reference positions.
        radius: localisation radius (same unit as positions); a reference within it is correct.
        positives: explicit positives over the items (query m ↔ reference items), used instead of
            the radius when given.
        matched: ``[M]`` bool, optional: whether each query has a correct reference among every reference frame,
            also those that are no item (a frame where no full window fits: a reference sequence shorter than L, or
            its ends). Such a query counts (a failure: no item is correct) instead of being left out as one without a
            correct reference, which would lift the sequence methods' R@K (hunt 6: 0.617 where 0.337 is right).
        frames: ``[R_all, P]``, optional, radius ground truth: the positions of every reference frame, items or
            not; :attr:`matched` is then the queries within the radius of one, at this radius and at each of
            :meth:`within`.
    """

    q_pos: np.ndarray
    r_pos: np.ndarray
    radius: float
    positives: Positives | None = None
    matched: np.ndarray | None = None
    frames: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.radius = check_radius(self.radius)
        self.q_pos, self.r_pos = positions_array(self.q_pos, "query"), positions_array(self.r_pos, "reference")
        if self.q_pos.shape[1] != self.r_pos.shape[1]:
            raise ConfigError(f"query positions are {self.q_pos.shape[1]}-D but reference positions "
                              f"{self.r_pos.shape[1]}-D")
        if self.positives is not None:
            self.positives.check(len(self.q_pos), len(self.r_pos), "positives over the evaluated items")
        if self.frames is not None and self.positives is None:
            self.frames = positions_array(self.frames, "reference frames")
            self.matched = has_positive(self.q_pos, self.frames, self.radius)
        if self.matched is not None:
            self.matched = np.asarray(self.matched, dtype=bool)
            if self.matched.shape != (len(self.q_pos),):
                raise ConfigError(f"matched must be [M] = [{len(self.q_pos)}] bool, got shape {self.matched.shape}")

    def has_positive(self) -> np.ndarray:
        """``[M]`` bool: whether the query has any correct reference (an item, or a frame of :attr:`matched`)."""
        return self.item_positive() | (self.matched if self.matched is not None else False)

    def item_positive(self) -> np.ndarray:
        """``[M]`` bool: whether the query has a correct reference among the items."""
        if self.positives is not None:
            return self.positives.counts() > 0
        return has_positive(self.q_pos, self.r_pos, self.radius)

    def of(self, m: int) -> np.ndarray:
        """The correct reference items of query item ``m``, sorted."""
        if self.positives is not None:
            return self.positives.of(m)
        return np.flatnonzero(np.linalg.norm(self.r_pos - self.q_pos[m], axis=1) <= self.radius)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(query items, reference items)`` of every correct pair (explicit positives, or within the radius:
        a KD-tree), by query item."""
        if self.positives is not None:
            return self.positives.pairs()
        from scipy.spatial import cKDTree

        lists = cKDTree(self.r_pos).query_ball_point(self.q_pos, r=self.radius)
        q = np.repeat(np.arange(len(lists)), [len(x) for x in lists])
        return q, np.fromiter((j for x in lists for j in sorted(x)), dtype=np.int64, count=len(q))

    def within(self, radius: float) -> GroundTruth:
        """The ground truth at another ``radius`` (``--extra-radius``): the radius itself; with explicit
        positives, the references within ``radius`` of one of the query's positives, measured between
        reference positions only (the query's own positions need not be comparable with the reference's: two
        traverses of different lengths, each numbered by frame). A query without a positive keeps none."""
        if self.positives is None:  # matched anew at that radius (a query may have no frame within a smaller one)
            return GroundTruth(self.q_pos, self.r_pos, radius, frames=self.frames)
        radius = check_radius(radius)
        blocks = list(near_pairs(*self.positives.pairs(), self.r_pos, radius))
        q, r = (np.concatenate(x) for x in zip(*blocks, strict=True)) if blocks else (np.zeros(0, np.int64),) * 2
        return GroundTruth(self.q_pos, self.r_pos, radius, Positives.from_pairs(q, r, len(self.q_pos)), self.matched)

    def hits(self, retrieved: np.ndarray) -> np.ndarray:
        """``[M, K]`` bool: whether ``retrieved[m, k]`` (a reference item, -1 = none) is correct."""
        if self.positives is not None:
            return self.positives.hits(retrieved)
        return hits(retrieved, self.q_pos, self.r_pos, self.radius)

    def without_soft(self, retrieved: np.ndarray, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(retrieved, scores)`` ``[M, K]`` without the soft-only positives (soft, not hard: VPR_Tutorial's
        ``GTsoft & ~GThard``), the rest moved up in order and padded with -1 / inf: as VPR_Tutorial's
        ``createPR`` sets their similarity to the minimum, so a soft match is neither a true nor a false
        positive. Unchanged without soft positives."""
        soft = self.positives.soft if self.positives is not None else None
        if soft is None or retrieved.shape[1] == 0:
            return retrieved, scores
        drop = soft.hits(retrieved) & ~self.positives.hits(retrieved)  # [M, K]
        order = np.argsort(drop, axis=1, kind="stable")  # kept first, in rank order
        kept = np.take_along_axis(retrieved, order, axis=1)
        moved = np.take_along_axis(drop, order, axis=1)
        s = np.take_along_axis(np.asarray(scores, dtype=np.float64), order, axis=1)
        return np.where(moved, -1, kept), np.where(moved, np.inf, s)

    def check_retrieved(self, retrieved: np.ndarray) -> np.ndarray:
        """``retrieved`` as an int64 ``[M, K]`` array of valid reference items (or -1)."""
        retrieved = retrieved_array(retrieved)
        if retrieved.ndim == 1:
            retrieved = retrieved[:, None]
        if retrieved.ndim != 2 or retrieved.shape[0] != len(self.q_pos):
            raise ConfigError(f"retrieved must be [{len(self.q_pos)}, K] (one row per query), got shape "
                              f"{retrieved.shape}")
        if retrieved.dtype.kind not in "iu":
            retrieved = integral(retrieved)
        retrieved = retrieved.astype(np.int64, copy=False)
        if retrieved.size and (retrieved.min() < -1 or retrieved.max() >= len(self.r_pos)):
            raise ConfigError(f"retrieved indices must lie in 0..{len(self.r_pos) - 1} (or -1 for none)")
        return retrieved


def ground_truth(q_pos: np.ndarray, r_pos: np.ndarray, radius: float, positives: Positives | None = None,
                 name: str = "the dataset", unit: str = "m", require: bool = True, *, frames: np.ndarray | None = None,
                 matched: np.ndarray | None = None) -> GroundTruth:
    """The one ground truth of evaluated items (evaluation, maps, the localiser); with ``require`` a
    :class:`ConfigError` when no query has a correct reference among the items (Recall@K would be undefined).
    The reference frames that are no item (where no full window fits) are given as ``frames`` (the positions of every
    reference frame; radius only, used when more than the items) or ``matched`` (``[M]``: the queries with a positive
    among them, explicit positives): :attr:`GroundTruth.matched`."""
    truth = GroundTruth(q_pos, r_pos, radius, positives)
    if require and not truth.has_positive().any():
        what = ("any of its explicit positives among the indexed references" if positives is not None else
                f"a reference within radius {radius:g} {unit}")
        hint = ("the radius plays no part with explicit positives: check that the positives list references for "
                "these queries (an empty list is no match) and that the split's reference range holds them"
                if positives is not None else "check the radius and its unit, the split, and that both traverses "
                "share one coordinate frame")
        raise ConfigError(f"none of the {len(q_pos)} evaluated queries of {name!r} has {what}, so Recall@K is "
                          f"undefined; hint: {hint}")
    if frames is not None and positives is None and len(frames) > len(truth.r_pos):
        return dataclasses.replace(truth, frames=np.asarray(frames))
    return truth if matched is None else dataclasses.replace(truth, matched=matched)
