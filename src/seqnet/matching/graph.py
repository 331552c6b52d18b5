"""Graph sequence matching (GISM-style) and its LSH-relocalised form (GRH-style), offline and online.

**Paths.** A query window of L frames starting at ``a`` is matched by a path of reference frames
``j_0 .. j_{L−1}`` with steps ``j_{t+1} − j_t ∈ {0 .. fan_out}`` (0: the camera stopped); its cost
is ``Σ_t ‖q[a + t] − r[j_t]‖₂``. A reference item (the window starting at ``b``) scores the
cheapest path through frame ``b + p`` at the pivot step ``p`` (``anchor`` as in
:mod:`seqnet.matching.velocity`: start / centre / end), so the fixed-speed path ``j_t = b + t`` is one of its
paths and the item's frame is the one matched to the query item's frame (centred windows, default
anchor). Paths stay inside the reference traverse; every item has a finite score.

**Dynamic program** over all reference frames at once, per block of query windows (``D`` = the
``[n + L − 1, Nr]`` distances): forward ``F_0 = D[a]``, ``F_t[j] = D[a + t, j] + min_{s ≤ fan_out}
F_{t−1}[j − s]`` up to the pivot; backward ``B_{L−1} = D[a + L − 1]``, ``B_t[j] = D[a + t, j] +
min_s B_{t+1}[j + s]`` down to ``p + 1``; the pivot cost is ``F_p[j] + min_s B_{p+1}[j + s]``. Each
transition is a running minimum over ``fan_out`` shifted columns plus one add.

**GRH** (:func:`grh_topk`): reference frames are hashed with ``faiss.IndexLSH`` (random rotation,
per-bit median thresholds trained on the reference); the ``candidates`` reference frames nearest in
Hamming distance to query frame ``a`` (ties: lower frame) are its relocalisation candidates, and a
path must *start* (step 0) within ``neighbourhood`` frames of one of them: ``F_0`` is ``+inf``
elsewhere. ``codes="dh"`` (``grh-dh``) takes learned codes instead (:mod:`seqnet.matching.hashing`).

**Online** (:class:`OnlineGraphMatcher`): see the class.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

from ..core.config import check_choice, check_float, check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.log import logger
from ..core.tensors import ArrayLike, as_tensor, to_numpy
from ..search.knn import as_pair, pairwise_distances, rows_per_block, sq_norms
from ..sequence.windows import check_seq_len
from .hashing import dh_candidates, hamming_topk
from .paths import path_dp, runmin
from .velocity import BlockFn, check_pairs, matcher_topk, pivot_step, score_blocks

torch = lazy_module("torch")

DEFAULT_FAN_OUT = 2


def _check(seq_len: int, fan_out: int, anchor: str) -> tuple[int, int]:
    check_seq_len(seq_len)
    return check_int("fan_out", fan_out, 0), pivot_step(anchor, seq_len)


def _graph_block(seq_len: int, fan_out: int, pivot: int, cands: torch.Tensor | None = None,
                 radius: int = 0, items: bool = True) -> BlockFn:
    def block(dist: torch.Tensor, a0: int, n: int) -> torch.Tensor:
        mask = None if cands is None else near_mask(cands[a0 : a0 + n], dist.shape[1], radius)
        out = path_dp(lambda t: dist[t : t + n], seq_len, fan_out, pivot, mask)
        return out[:, pivot : pivot + dist.shape[1] - seq_len + 1] if items else out
    return block


def graph_topk(query: ArrayLike, ref: ArrayLike, seq_len: int, k: int, q_starts: np.ndarray, r_starts: np.ndarray,
               fan_out: int = DEFAULT_FAN_OUT, anchor: str = "centre", device: str | None = None,
               block_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Whole-map graph matching: ``(scores [M, k], items [M, k])`` per query window ``q_starts [M]``."""
    fan_out, pivot = _check(seq_len, fan_out, anchor)
    return matcher_topk(lambda q, r: _graph_block(seq_len, fan_out, pivot), query, ref, seq_len, k, q_starts,
                        r_starts, 5, device, block_bytes, "graph matching")


def path_costs(query: ArrayLike, ref: ArrayLike, seq_len: int, fan_out: int = DEFAULT_FAN_OUT,
               anchor: str = "centre", device: str | None = None, block_bytes: int | None = None) -> np.ndarray:
    """``[Nq − L + 1, Nr]``: the cheapest path of each query window through each reference frame at the
    pivot step. The item map (item b ↔ frame b + p) is ``path_costs(...)[:, p : p + Nr − L + 1]``."""
    fan_out, pivot = _check(seq_len, fan_out, anchor)
    q, r = as_pair(query, ref, get_device(device))
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    block_fn = _graph_block(seq_len, fan_out, pivot, items=False)
    return np.concatenate([to_numpy(m) for _, m in score_blocks(block_fn, q, r, seq_len, 5, block_bytes)])


@no_grad
def graph_pairs(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
                fan_out: int = DEFAULT_FAN_OUT, anchor: str = "centre", block_bytes: int | None = None,
                start_mask: Callable[[slice, torch.Tensor], torch.Tensor] | None = None) -> torch.Tensor:
    """Graph-matching scores ``[M, K]`` of query windows ``q_starts [M]`` vs reference windows ``cand [M, K]``.

    The same score as :func:`graph_topk`: the cheapest path through frame ``cand + p`` at step p,
    found by the DP on the ``W = fan_out · (L − 1) + 1`` frames such paths can reach (distances by the
    norm trick, one batched GEMM ``[K·W, D] × [D, L]`` per query window, as in the whole map). -1
    scores ``inf``.
    ``start_mask(rows, frames [m, K, W])`` (GRH) says where paths may start.
    """
    fan_out, pivot = _check(seq_len, fan_out, anchor)
    q_starts, cand = check_pairs(q, r, seq_len, q_starts, cand)
    width = fan_out * (seq_len - 1) + 1
    out = torch.full(cand.shape, math.inf, dtype=q.dtype, device=q.device)
    rows = rows_per_block(max(1, cand.shape[1]) * width * (q.shape[1] + 2 * seq_len) * q.element_size(), block_bytes)
    cols = torch.arange(width, device=q.device) - fan_out * pivot
    q_sq, r_sq = sq_norms(q), sq_norms(r)
    for s in range(0, cand.shape[0], rows):
        q_win = q_starts[s : s + rows, None] + torch.arange(seq_len, device=q.device)  # [m, L]
        frames = (cand[s : s + rows] + pivot)[..., None] + cols  # [m, K, W]: frame of each column
        inside = (frames >= 0) & (frames < r.shape[0])
        safe = frames.clamp(0, r.shape[0] - 1).flatten(1)  # [m, K·W]
        dist = torch.bmm(r[safe], q[q_win].transpose(1, 2)).mul_(-2.0)  # [m, K·W, L]: −2 r·q
        dist.add_(r_sq[safe][..., None]).add_(q_sq[q_win][:, None, :]).clamp_min_(0.0).sqrt_()  # norm trick
        dist = dist.view(*frames.shape, seq_len).masked_fill_(~inside[..., None], math.inf)
        mask = None if start_mask is None else start_mask(slice(s, s + rows), frames)
        out[s : s + rows] = path_dp(lambda t, d=dist: d[..., t], seq_len, fan_out, pivot, mask)[..., fan_out * pivot]
    return out.masked_fill_(cand < 0, math.inf)


# ----------------------------------------------------------------------------- GRH


WIDE_LSH = 4096  # above this D the LSH rotation costs seconds: grh says so


@functools.cache
def _warn_wide(dim: int) -> None:
    """Say once per D that grh's LSH codes of wide descriptors dominate its cost."""
    logger.warning("grh: LSH codes of D=%d descriptors (a random rotation of D x D) dominate the cost; "
                   "s1+grh or a PCA'd descriptor is much faster (docs/matchers.md)", dim)


@no_grad
def lsh_candidates(query: ArrayLike, ref: ArrayLike, nbits: int = 256, candidates: int = 20,
                   device: str | None = None, block_bytes: int | None = None) -> np.ndarray:
    """``[Nq, min(candidates, Nr)]`` reference frames nearest to each query frame in LSH Hamming distance.

    Codes come from ``faiss.IndexLSH(D, nbits, rotate_data=True, train_thresholds=True)`` trained on
    ``ref`` (deterministic); Hamming distances are one GEMM of the bits per block and the smallest
    are kept with ties broken by the lower frame index (deterministic, unlike a heap).
    """
    import faiss

    nbits, candidates = check_int("nbits", nbits, 1), check_int("candidates", candidates, 1)
    dev = get_device(device)
    q, r = (t.cpu().float().numpy() for t in as_pair(query, ref, torch.device("cpu")))
    if r.shape[1] > WIDE_LSH:
        _warn_wide(int(r.shape[1]))
    index = faiss.IndexLSH(r.shape[1], nbits, True, True)
    index.train(np.ascontiguousarray(r))
    bq, br = (torch.as_tensor(np.unpackbits(index.sa_encode(np.ascontiguousarray(x)), axis=1, bitorder="little")
                              [:, :nbits], dtype=torch.float32, device=dev) for x in (q, r))
    return hamming_topk(bq, br, candidates, block_bytes)


# where GRH's relocalisation candidates come from: codes of frames, nearest in Hamming distance
GRH_CODES: dict[str, Callable[..., np.ndarray]] = {"lsh": lsh_candidates, "dh": dh_candidates}


def near_mask(cands: torch.Tensor, n_ref: int, radius: int) -> torch.Tensor:
    """``[n, Nr]`` bool: frames within ``radius`` of one of the frames ``cands [n, c]`` (-1: none)."""
    lo = torch.where(cands >= 0, (cands - radius).clamp(0, n_ref), n_ref)
    hi = torch.where(cands >= 0, (cands + radius + 1).clamp(0, n_ref), n_ref)
    edges = torch.zeros((cands.shape[0], n_ref + 1), dtype=torch.int32, device=cands.device)
    edges.scatter_add_(1, lo, torch.ones_like(lo, dtype=torch.int32))
    edges.scatter_add_(1, hi, torch.full_like(hi, -1, dtype=torch.int32))
    return edges.cumsum(1, dtype=torch.int32)[:, :n_ref] > 0


def _grh_args(nbits: int, candidates: int, neighbourhood: int, codes: str) -> int:
    check_choice("GRH codes", codes, GRH_CODES)
    check_int("nbits", nbits, 1)
    check_int("candidates", candidates, 1)
    return check_int("neighbourhood", neighbourhood, 0)


def grh_topk(query: ArrayLike, ref: ArrayLike, seq_len: int, k: int, q_starts: np.ndarray, r_starts: np.ndarray,
             fan_out: int = DEFAULT_FAN_OUT, nbits: int = 256, candidates: int = 20, neighbourhood: int = 10,
             anchor: str = "centre", device: str | None = None, block_bytes: int | None = None,
             codes: str = "lsh") -> tuple[np.ndarray, np.ndarray]:
    """Graph matching whose paths start within ``neighbourhood`` frames of a candidate of the query
    window's first frame (``codes``: a key of :data:`GRH_CODES`; see the module docstring); items
    without such a path score ``inf``."""
    fan_out, pivot = _check(seq_len, fan_out, anchor)
    radius = _grh_args(nbits, candidates, neighbourhood, codes)

    def prepare(q: torch.Tensor, r: torch.Tensor) -> BlockFn:
        cands = torch.as_tensor(GRH_CODES[codes](q[: q.shape[0] - seq_len + 1], r, nbits, candidates, q.device),
                                device=q.device)
        return _graph_block(seq_len, fan_out, pivot, cands, radius)

    return matcher_topk(prepare, query, ref, seq_len, k, q_starts, r_starts, 8, device, block_bytes, "GRH")


def grh_pairs(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
              fan_out: int = DEFAULT_FAN_OUT, nbits: int = 256, candidates: int = 20, neighbourhood: int = 10,
              anchor: str = "centre", block_bytes: int | None = None, codes: str = "lsh") -> torch.Tensor:
    """GRH scores ``[M, K]`` of given window pairs: :func:`graph_pairs` with the start restriction of ``codes``."""
    radius = _grh_args(nbits, candidates, neighbourhood, codes)
    q_starts, _ = check_pairs(q, r, seq_len, q_starts, cand)
    firsts, inverse = torch.unique(q_starts, return_inverse=True)
    firsts_cands = torch.as_tensor(GRH_CODES[codes](q[firsts], r, nbits, candidates, q.device), device=q.device)

    def start_mask(rows: slice, frames: torch.Tensor) -> torch.Tensor:
        c = firsts_cands[inverse[rows]][:, None, None, :]  # [m, 1, 1, c]
        return ((c - frames[..., None]).abs() <= radius).any(-1)

    return graph_pairs(q, r, seq_len, q_starts, cand, fan_out, anchor, block_bytes, start_mask)


# ----------------------------------------------------------------------------- online


class OnlineGraphMatcher:
    """Frame-by-frame graph matching with "no match" nodes and relocalisation.

    State: two rows over the reference frames, ``C [Nr]`` (cheapest path since the last (re)start
    whose current query frame matches reference frame j) and ``H [Nr]`` (the same, but the current
    frame is a *no match* at route position j, cost ``no_match_cost``; no-match nodes follow the
    route with the same steps, like GISM's hidden nodes). A step with query descriptor ``x`` and
    distances ``d = ‖x − r_j‖`` (one GEMV):
    ``M = runmin_{fan_out}(min(C, H))``, ``C ← M + d``, ``H ← M + no_match_cost``; the first frame
    after a (re)start has ``M = 0``. The step returns ``(j, cost)`` of the cheapest node: ``j`` for a
    match node, ``-1`` for a no-match node; ``cost`` is that path's total cost since the (re)start.

    Relocalisation: after ``relocalise_after`` consecutive no-match answers the path restarts: the
    next frame starts from its own distances (the global nearest reference wins). With
    ``no_match_cost=None`` there are no no-match nodes, and a step equals the offline graph DP
    (:func:`path_costs`, ``anchor="end"``) over the causal window from the (re)start to this frame.
    ``length`` counts the frames since the last (re)start (``cost / length``: cost per frame).
    """

    def __init__(self, ref: ArrayLike, fan_out: int = DEFAULT_FAN_OUT, no_match_cost: float | None = None,
                 relocalise_after: int = 3, device: str | None = None):
        self.ref = as_tensor(ref, get_device(device), "reference", ndim=2, keep_float64=True)
        self.fan_out = check_int("fan_out", fan_out, 0)
        self.no_match_cost = None if no_match_cost is None else check_float("no_match_cost", no_match_cost, 0.0)
        self.relocalise_after = check_int("relocalise_after", relocalise_after, 1)
        self.reset()

    def reset(self) -> None:
        """Forget the path: the next frame starts afresh."""
        self.cost: torch.Tensor | None = None  # [2, Nr]: C and H, minus ``offset``
        self.offset, self.length, self.lost = 0.0, 0, 0

    @no_grad
    def step(self, descriptor: ArrayLike) -> tuple[int, float]:
        """Match the next query frame ``descriptor [D]``: ``(reference frame or -1, path cost)``."""
        x = as_tensor(descriptor, self.ref.device, "descriptor", ndim=1, keep_float64=True).to(self.ref.dtype)
        if x.shape[0] != self.ref.shape[1]:
            raise ConfigError(f"descriptor must have D={self.ref.shape[1]}, got {x.shape[0]}")
        if self.lost >= self.relocalise_after:  # relocalise: this frame starts a new path
            self.reset()
        d = pairwise_distances(x[None], self.ref)[0]
        prev = torch.zeros_like(d) if self.cost is None else runmin(self.cost.amin(0), self.fan_out)
        lam = math.inf if self.no_match_cost is None else self.no_match_cost
        cost = torch.stack([prev + d, prev + lam])
        low = cost.amin()
        self.cost, self.offset, self.length = cost - low, self.offset + float(low), self.length + 1
        j = int(torch.argmin(cost[0]))
        lost = bool(cost[0, j] > low)
        self.lost = self.lost + 1 if lost else 0  # consecutive no-match answers
        return (-1 if lost else j), self.offset

