"""HVPR (hierarchical VPR): the one path from a shortlist to a full ranking.

Shortlist the top-K reference items of each query item by descriptor distance (k-NN on any
sequence or single descriptor, e.g. S_L), re-rank the shortlist with a sequence matcher on frame
descriptors (SeqMatch on S_1 in the paper), and return the full ranking: the re-ranked shortlist,
then the rest of the k-NN list in shortlist order.

*Fused* re-ranking (``fuse=λ > 0``, method ``hvpr-fused``) scores each shortlisted window by the
matcher's mean per-frame distance plus λ times its shortlist distance,
``score = matcher / L_m + λ · d_shortlist``, so that a candidate the sequence descriptor and the
matcher both like wins over one only the matcher likes; ``fuse=0`` is the paper's re-ranking.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.config import check_choice, check_float, check_int
from ..core.errors import ConfigError
from ..core.utils import ArrayLike, get_device, to_numpy
from ..search.knn import as_pair, knn
from ..sequence.windows import check_seq_len
from .registry import SEQUENCE_MATCHERS
from .seqmatch import check_starts


def hvpr(
    shortlist_query: ArrayLike,
    shortlist_ref: ArrayLike,
    rerank_query: ArrayLike,
    rerank_ref: ArrayLike,
    seq_len: int,
    q_starts: np.ndarray,
    r_starts: np.ndarray,
    top_k: int = 20,
    k: int | None = None,
    matcher: str = "seqmatch",
    backend: str = "torch",
    device: str | None = None,
    fuse: float = 0.0,
    window: str = "centred",
) -> tuple[np.ndarray, np.ndarray]:
    """Hierarchical VPR: shortlist by descriptor distance, re-rank by a sequence matcher.

    Args:
        shortlist_query: ``[M, D1]`` shortlisting descriptors of the query items (e.g. S_L).
        shortlist_ref: ``[R, D1]`` shortlisting descriptors of the reference items.
        rerank_query: ``[Nq, D2]`` frame descriptors of all query frames (raw or S_1).
        rerank_ref: ``[Nr, D2]`` frame descriptors of all reference frames.
        seq_len: matching length L_m.
        q_starts: ``[M]`` matching-window start (in ``rerank_query``) of each query item.
        r_starts: ``[R]`` matching-window start (in ``rerank_ref``) of each reference item.
        top_k: shortlist size K (default 20).
        k: length of the returned ranking (default K; beyond K the k-NN order continues).
        matcher: a key of :data:`seqnet.matching.registry.SEQUENCE_MATCHERS`.
        backend: k-NN backend of the shortlist.
        fuse: λ >= 0 of the fused score ``matcher / L_m + λ · d_shortlist`` (0: the matcher score alone).
        window: ``"centred"`` or ``"causal"`` windows (anchored matchers pin the item's frame in them).

    Returns:
        ``(scores [M, max(k, K)], items [M, max(k, K)])``: reference items, the re-ranked shortlist
        first (ascending matcher or fused score), then the rest of the k-NN list (score ``inf``).
    """
    top_k = check_int("top_k", top_k, 1)
    k = top_k if k is None else check_int("k", k, 1)
    fuse = check_float("fuse", fuse, 0.0)
    dist, ranked = knn(shortlist_query, shortlist_ref, max(k, top_k), backend=backend, device=device)
    head = min(top_k, ranked.shape[1])
    prior = fuse * dist[:, :head] if fuse > 0 else None
    scores, items = rerank(rerank_query, rerank_ref, seq_len, q_starts, r_starts, ranked[:, :head], matcher, device,
                           prior, window)
    tail = np.full((len(ranked), ranked.shape[1] - head), np.inf, dtype=scores.dtype)
    return np.concatenate([scores, tail], axis=1), np.concatenate([items, ranked[:, head:]], axis=1)


@torch.no_grad()
def rerank(
    rerank_query: ArrayLike,
    rerank_ref: ArrayLike,
    seq_len: int,
    q_starts: np.ndarray,
    r_starts: np.ndarray,
    candidates: np.ndarray,
    matcher: str = "seqmatch",
    device: str | None = None,
    prior: np.ndarray | None = None,
    window: str = "centred",
) -> tuple[np.ndarray, np.ndarray]:
    """Re-rank candidate reference items ``[M, K]`` with a sequence matcher (see :func:`hvpr`).

    ``candidates`` holds indices into ``r_starts``; ``-1`` marks no candidate (scored ``inf``,
    ranked last, returned as ``-1``). With ``prior [M, K]`` the score is ``matcher / L + prior``
    (the fused score of :func:`hvpr`). Returns ``(scores [M, K], items [M, K])`` sorted by
    ascending score (stable: ties keep the shortlist order).
    """
    spec = SEQUENCE_MATCHERS[check_choice("sequence matcher", matcher, SEQUENCE_MATCHERS)]
    dev = get_device(device)
    q, r = as_pair(rerank_query, rerank_ref, dev)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    na, nb = q.shape[0] - seq_len + 1, r.shape[0] - seq_len + 1
    q_starts_np = check_starts(q_starts, na, "query")
    r_starts_t = torch.as_tensor(check_starts(r_starts, nb, "reference"), device=dev)
    cand = np.asarray(to_numpy(candidates) if isinstance(candidates, torch.Tensor) else candidates)
    if cand.ndim != 2 or cand.shape[0] != len(q_starts_np) or (cand.size and cand.dtype.kind not in "iu"):
        raise ConfigError(
            f"candidates must be an integer [{len(q_starts_np)}, K] array (one row per query item), "
            f"got shape {cand.shape}, dtype {cand.dtype}"
        )
    if cand.size and (cand.min() < -1 or cand.max() >= len(r_starts_t)):
        raise ConfigError(f"candidates must be reference items in 0..{len(r_starts_t) - 1} (or -1 for none)")
    cand_t = torch.as_tensor(cand.astype(np.int64, copy=False), device=dev)
    cand_starts = torch.where(cand_t >= 0, r_starts_t[cand_t.clamp_min(0)], -1) if len(r_starts_t) else cand_t
    scores = spec.score_pairs(q, r, seq_len, torch.as_tensor(q_starts_np, device=dev), cand_starts,
                              **spec.options(window))
    if prior is not None:
        if np.shape(prior) != cand.shape:
            raise ConfigError(f"prior must have the candidates' shape {cand.shape}, got {np.shape(prior)}")
        scores = scores / seq_len + torch.as_tensor(np.asarray(prior), device=dev, dtype=scores.dtype)
    order = torch.sort(scores, dim=1, stable=True).indices
    return to_numpy(scores.gather(1, order)), to_numpy(cand_t.gather(1, order))
