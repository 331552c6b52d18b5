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

from collections.abc import Callable

import numpy as np

from ..core.config import check_choice, check_float, check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.tensors import ArrayLike, to_numpy
from ..search.api import prepared
from ..search.knn import as_pair, knn
from ..sequence.windows import MODE_ANCHORS, check_seq_len
from .pairs import item_starts
from .registry import SEQUENCE_MATCHERS
from .seqmatch import check_starts

torch = lazy_module("torch")

Search = Callable[[int], tuple[np.ndarray, np.ndarray]]  # n -> (distances [M, n], items [M, n]) of the shortlist
PairScores = Callable[[np.ndarray], "torch.Tensor"]  # candidates [M, K] -> matcher scores [M, K] (candidate order)


def hvpr_search(search: Search, pair_scores: PairScores, seq_len: int, top_k: int = 20, k: int | None = None,
                fuse: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """HVPR, the one assembly: shortlist the top ``top_k`` by ``search``, score them with ``pair_scores``
    (the matcher on the candidates' windows), order them, then the rest of the shortlist.

    Evaluation, maps and the localiser all call this through :func:`seqnet.methods.rank.rank`; the
    array API :func:`hvpr` calls it with exact k-NN. With ``fuse = λ > 0`` the score is
    ``matcher / L_m + λ · d_shortlist``. Returns ``(scores [M, max(k, K)], items [M, max(k, K)])``:
    the re-ranked head (ascending, ties in shortlist order), then the k-NN tail (score ``inf``).
    """
    top_k = check_int("top_k", top_k, 1)
    k = top_k if k is None else check_int("k", k, 1)
    fuse = check_float("fuse", fuse, 0.0)
    dist, ranked = search(max(k, top_k))
    head = min(top_k, ranked.shape[1])
    scores, items = order(pair_scores(ranked[:, :head]), ranked[:, :head], seq_len,
                          fuse * dist[:, :head] if fuse > 0 else None)
    tail = np.full((len(ranked), ranked.shape[1] - head), np.inf, dtype=scores.dtype)
    return np.concatenate([scores, tail], axis=1), np.concatenate([items, ranked[:, head:]], axis=1)


def order(scores: torch.Tensor, candidates: np.ndarray, seq_len: int,
          prior: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sort candidates ``[M, K]`` by their matcher ``scores [M, K]`` (stable: ties keep the shortlist
    order); with ``prior [M, K]`` by ``scores / L_m + prior`` (the fused score)."""
    if prior is not None:
        if np.shape(prior) != candidates.shape:
            raise ConfigError(f"prior must have the candidates' shape {candidates.shape}, got {np.shape(prior)}")
        scores = scores / seq_len + torch.as_tensor(np.asarray(prior), device=scores.device, dtype=scores.dtype)
    cand_t = torch.as_tensor(candidates, device=scores.device)
    idx = torch.sort(scores, dim=1, stable=True).indices
    return to_numpy(scores.gather(1, idx)), to_numpy(cand_t.gather(1, idx))


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
    normalize: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hierarchical VPR on arrays: shortlist by exact k-NN, re-rank by a sequence matcher (:func:`hvpr_search`).

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
        normalize: ``True``: L2-normalise every row of the four arrays first, as ``evaluate()`` and ``seqnet
            eval`` do; ``None`` (default): compare the rows as given, with a WARNING line (once a process) when
            rows are far from unit norm; ``False``: as given, no unit-norm check (as :func:`seqnet.knn`).

    Returns ``(scores [M, max(k, K)], items [M, max(k, K)])``: reference items, the re-ranked shortlist first
    (ascending matcher or fused score), then the rest of the k-NN list (score ``inf``).
    """
    anchor = MODE_ANCHORS[check_choice("window mode", window, MODE_ANCHORS)]
    _one_per_row(q_starts, r_starts, len(shortlist_query), len(shortlist_ref))
    shortlist_query, shortlist_ref = prepared(shortlist_query, shortlist_ref, "hvpr", normalize,
                                              ("shortlist query", "shortlist reference"))
    rerank_query, rerank_ref = prepared(rerank_query, rerank_ref, "hvpr", normalize,
                                        ("re-rank query", "re-rank reference"))
    return hvpr_search(lambda n: knn(shortlist_query, shortlist_ref, n, backend=backend, device=device),
                       lambda c: pair_scores(rerank_query, rerank_ref, seq_len, q_starts, r_starts, c, matcher,
                                             device, anchor), seq_len, top_k, k, fuse)


def _one_per_row(q_starts: ArrayLike, r_starts: ArrayLike, m: int, r: int) -> None:
    """A :class:`ConfigError` unless ``q_starts`` is ``[m]`` and ``r_starts`` ``[r]``: one window start per row of
    ``shortlist_query`` / ``shortlist_ref`` (checked before :func:`pair_scores`, whose errors name its arguments)."""
    for starts, name, n, of in ((q_starts, "q_starts", m, "shortlist_query"),
                                (r_starts, "r_starts", r, "shortlist_ref")):
        shape = tuple(starts.shape) if hasattr(starts, "shape") else np.shape(starts)
        if shape != (n,):
            raise ConfigError(f"{name} must have one entry per {of} row ({n}), got "
                              f"{shape[0] if len(shape) == 1 else f'shape {shape}'}")


@no_grad
def pair_scores(rerank_query: ArrayLike, rerank_ref: ArrayLike, seq_len: int, q_starts: np.ndarray,
                r_starts: np.ndarray, candidates: np.ndarray, matcher: str = "seqmatch", device: str | None = None,
                anchor: str = "centre") -> torch.Tensor:
    """The matcher's scores ``[M, K]`` of candidate reference items ``candidates [M, K]`` (indices into
    ``r_starts``; ``-1`` = none, scored ``inf``) for the query windows ``q_starts [M]``, in candidate order.
    Checks every argument, then :func:`candidate_scores`."""
    check_choice("sequence matcher", matcher, SEQUENCE_MATCHERS)
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
    return candidate_scores(q, r, seq_len, torch.as_tensor(q_starts_np, device=dev), r_starts_t, cand, matcher,
                            anchor)


def candidate_scores(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, r_starts: torch.Tensor,
                     candidates: np.ndarray | torch.Tensor, matcher: str, anchor: str) -> torch.Tensor:
    """The kernel of :func:`pair_scores` on checked inputs (a Reference's own descriptors and window
    starts, candidates from its search): ``q [Nq, D]``, ``r [Nr, D]`` of one dtype and device,
    ``q_starts [M]``, ``r_starts [R]``, ``candidates [M, K]`` items (``-1``: none) → ``[M, K]``."""
    spec = SEQUENCE_MATCHERS[matcher]
    return spec.score_pairs(q, r, seq_len, q_starts, item_starts(candidates, r_starts), **spec.options(anchor))


def rerank(rerank_query: ArrayLike, rerank_ref: ArrayLike, seq_len: int, q_starts: np.ndarray, r_starts: np.ndarray,
           candidates: np.ndarray, matcher: str = "seqmatch", device: str | None = None,
           prior: np.ndarray | None = None, window: str = "centred") -> tuple[np.ndarray, np.ndarray]:
    """Re-rank candidate reference items ``[M, K]`` with a sequence matcher: :func:`pair_scores`, then
    :func:`order` (``prior``: the fused score). Returns ``(scores [M, K], items [M, K])``, ascending."""
    anchor = MODE_ANCHORS[check_choice("window mode", window, MODE_ANCHORS)]
    cand = np.asarray(to_numpy(candidates) if isinstance(candidates, torch.Tensor) else candidates)
    scores = pair_scores(rerank_query, rerank_ref, seq_len, q_starts, r_starts, cand, matcher, device, anchor)
    return order(scores, cand.astype(np.int64, copy=False), seq_len, prior)
