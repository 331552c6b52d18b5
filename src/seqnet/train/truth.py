"""What a training query's positives and negatives are: by radius, or from the dataset's explicit positives.

With positions only, a reference window is a positive within ``pos_radius`` of the query and a
negative beyond ``neg_radius`` (NetVLAD / SeqNet). With explicit positives (:mod:`seqnet.data.positives`),
the positives are the listed references and the negatives the references farther than ``neg_radius``
from every positive of the query, measured between reference positions (the query's own positions
need not be comparable with the reference's: other counts, an offset), that are not soft positives
either (VPR_Tutorial's GTsoft), so a place the lists know about, or its neighbours, is never taken for
a negative.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..core.lazy import lazy_module
from ..data.positives import Positives
from ..metrics.recall import near_pairs

torch = lazy_module("torch")


def queries_with_pairs(q_pos: np.ndarray, r_pos: np.ndarray, pos_radius: float, neg_radius: float,
                       positives: Positives | None = None) -> np.ndarray:
    """``[M]`` bool: whether query position ``q_pos [M, P]`` has at least one positive (a reference
    position ``r_pos [R, P]`` within ``pos_radius``, or an explicit positive) and one negative (beyond
    ``neg_radius`` of the query, or with explicit positives of all its positives: :func:`pair_masks`)."""
    if positives is not None:
        keys, has_neg = positive_keys(positives, len(r_pos)), np.zeros(len(q_pos), dtype=bool)
        soft = nonnegative_keys(positives, len(r_pos))
        for s in range(0, len(q_pos), 4096):  # blocks of queries bound the [B, R] masks
            rows = torch.arange(s, min(len(q_pos), s + 4096))
            neg = pair_masks(torch.as_tensor(q_pos[s : s + 4096]), torch.as_tensor(r_pos), pos_radius, neg_radius,
                             keys, rows, soft)[1]
            has_neg[s : s + len(rows)] = neg.any(dim=1).numpy()
        return (positives.counts() > 0) & has_neg
    tree = cKDTree(np.asarray(r_pos, dtype=np.float64))
    q = np.asarray(q_pos, dtype=np.float64)
    n_pos = tree.query_ball_point(q, pos_radius, return_length=True)
    n_near = tree.query_ball_point(q, neg_radius, return_length=True)
    return (np.asarray(n_pos) > 0) & (np.asarray(n_near) < len(r_pos))


def radius_masks(
    q_pos: torch.Tensor, r_pos: torch.Tensor, pos_radius: float, neg_radius: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Positive (``dist <= pos_radius``) and negative (``dist > neg_radius``) masks ``[B, R]``.

    ``q_pos [B, P]`` and ``r_pos [R, P]`` should be float64 (UTM coordinates lose metres in float32).
    """
    origin = r_pos[:1]
    dist = torch.cdist(q_pos - origin, r_pos - origin, compute_mode="donot_use_mm_for_euclid_dist")
    return dist <= pos_radius, dist > neg_radius


def positive_keys(positives: Positives, n_refs: int) -> torch.Tensor:
    """The explicit positive pairs (query row q, reference column r) as sorted keys ``q * n_refs + r``."""
    rows, cols = positives.pairs()
    return torch.as_tensor(np.sort(rows.astype(np.int64) * n_refs + cols))


def nonnegative_keys(positives: Positives, n_refs: int) -> torch.Tensor | None:
    """The pairs that are never negatives besides the positives: the soft positives' keys (None without)."""
    return positive_keys(positives.soft, n_refs) if positives.soft is not None else None


def pair_masks(q_pos: torch.Tensor, r_pos: torch.Tensor, pos_radius: float, neg_radius: float,
               keys: torch.Tensor | None, rows: torch.Tensor,
               soft_keys: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Positive and negative masks ``[B, R]`` of the training queries ``rows [B]`` (positions ``q_pos [B, P]``):
    by radius, or, with explicit positive ``keys`` (:func:`positive_keys`), the listed pairs and the
    references farther than ``neg_radius`` from every listed one (:func:`near_listed`; ``q_pos`` is
    then not used) that are not soft positives (``soft_keys``) either."""
    if keys is None:
        return radius_masks(q_pos, r_pos, pos_radius, neg_radius)
    n = r_pos.shape[0]
    listed = key_mask(keys, rows, n).to(r_pos.device)
    neg = ~near_listed(listed, r_pos, neg_radius)
    if soft_keys is not None:
        neg = neg & ~key_mask(soft_keys.to(keys.device), rows, n).to(r_pos.device)
    return listed, neg


def key_mask(keys: torch.Tensor, rows: torch.Tensor, n: int) -> torch.Tensor:
    """``[B, n]`` bool: the pairs of sorted ``keys`` (:func:`positive_keys`) of the query rows ``rows [B]``: each
    row's keys found by binary search, O(keys of the rows), not a test of every (row, reference) pair."""
    rows = rows.to(keys.device)
    lo, hi = torch.searchsorted(keys, rows * n), torch.searchsorted(keys, (rows + 1) * n)
    counts = hi - lo
    b = torch.repeat_interleave(torch.arange(len(rows), device=keys.device), counts)
    first = torch.repeat_interleave(lo - (torch.cumsum(counts, 0) - counts), counts)  # keys[first + j]: j-th pair
    k = keys[first + torch.arange(len(b), device=keys.device)]
    mask = torch.zeros((len(rows), n), dtype=torch.bool, device=keys.device)
    mask[b, k - rows[b] * n] = True
    return mask


def near_listed(listed: torch.Tensor, r_pos: torch.Tensor, radius: float, block_elems: int = 2**24) -> torch.Tensor:
    """``[B, R]`` bool: whether reference r lies within ``radius`` of one of the references ``listed [B, R]``
    for row b (reference-to-reference distances of ``r_pos [R, P]``); the listed pairs themselves included.

    The neighbours come from :func:`seqnet.metrics.recall.near_pairs` (one k-d tree query per distinct listed
    reference), written in blocks of at most ``block_elems`` (row, reference) pairs."""
    b, p = (t.cpu().numpy() for t in listed.nonzero(as_tuple=True))
    near = torch.zeros(listed.shape, dtype=torch.bool, device=listed.device)
    for rows, cols in near_pairs(b, p, r_pos.cpu().numpy(), radius, block_elems):
        near[torch.as_tensor(rows, device=near.device), torch.as_tensor(cols, device=near.device)] = True
    return near
    pts = r_pos.cpu().numpy().astype(np.float64)
    pts = pts - pts[:1]  # UTM coordinates lose metres in float32; the tree works in float64 all the same
    uniq, inv = np.unique(p, return_inverse=True)
    balls = cKDTree(pts).query_ball_point(pts[uniq], radius)
    lens = np.fromiter((len(x) for x in balls), dtype=np.int64, count=len(balls))
    flat, starts = np.concatenate([np.asarray(x, dtype=np.int64) for x in balls]), np.cumsum(lens) - lens
    cnt = lens[inv]  # neighbours of each listed pair's reference
    ends = np.cumsum(cnt)
    s = 0
    while s < len(b):  # blocks of pairs writing at most block_elems entries (at least one pair)
        e = max(s + 1, int(np.searchsorted(ends, ends[s] - cnt[s] + block_elems, side="right")))
        c = cnt[s:e]
        rows = np.repeat(b[s:e], c)
        cols = flat[np.repeat(starts[inv[s:e]] - (np.cumsum(c) - c), c) + np.arange(c.sum())]
        near[torch.as_tensor(rows, device=near.device), torch.as_tensor(cols, device=near.device)] = True
        s = e
    return near
