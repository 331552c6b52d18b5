"""Triplet mining for SeqNet training (NetVLAD style), vectorised over a batch of queries.

For each training query (a window of the query traverse):

* **positive**: among the reference windows within ``pos_radius`` (position distance; or the
  dataset's explicit positives), the closest in descriptor space (descriptors cached by the current model);
* **negatives**: about ``n_sample`` reference windows drawn at random among those farther than
  ``neg_radius`` (from the query; with explicit positives, from every positive of the query, between
  reference positions: :func:`~seqnet.train.truth.pair_masks`), plus the query's hard negatives of the
  previous round (NetVLAD's negative cache); the ``n_neg`` closest of them in descriptor space are
  kept, and only those that violate the margin (``d_neg < d_pos + margin``) make triplets. A query
  without any is skipped.

Everything is one ``[B, R]`` distance matrix and masks: no loop per query or per negative. The
reference side of the mining cache (:class:`ReferenceCache`) is spilled to a temporary file when it
is large and computed on the CPU (:mod:`seqnet.core.memmaps`), and the distances are computed over
it in column blocks of :data:`~seqnet.search.blocks.COL_BLOCK_BYTES`, held or spilled alike.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..core.lazy import lazy_module
from ..core.memmaps import take_rows
from ..core.tensors import as_tensor
from ..search.blocks import COL_BLOCK_BYTES
from ..search.blocks import rows as read_block
from ..search.knn import pairwise_distances
from ..sequence.descriptors import describe_windows
from .config import MiningConfig
from .source import TripletSource
from .truth import pair_masks

torch = lazy_module("torch")


@dataclasses.dataclass
class Mined:
    """Triplets mined for a batch of B queries (indices are reference items, -1 = none).

    Attributes:
        positive: ``[B]`` chosen positive; ``d_pos``: ``[B]`` its cached-descriptor distance.
        negatives: ``[B, K]`` hardest negatives, closest first; ``valid``: ``[B, K]`` bool.
        d_neg: ``[B, K]`` cached-descriptor distances of ``negatives`` (inf where none).
    """

    positive: torch.Tensor
    d_pos: torch.Tensor
    negatives: torch.Tensor
    valid: torch.Tensor
    d_neg: torch.Tensor

    @property
    def has_triplet(self) -> torch.Tensor:
        """``[B]`` bool: the query has a positive and at least one valid negative."""
        return (self.positive >= 0) & self.valid.any(dim=1)

    def __getitem__(self, rows: slice | torch.Tensor) -> Mined:
        """The triplets of some of the queries (a slice or an index / mask over B)."""
        return Mined(*(getattr(self, f.name)[rows] for f in dataclasses.fields(self)))

    @staticmethod
    def cat(parts: list[Mined]) -> Mined:
        """Concatenate the triplets of consecutive query blocks."""
        return Mined(*(torch.cat([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(Mined)))


@dataclasses.dataclass
class ReferenceCache:
    """The current model's mining descriptors of R reference windows.

    Attributes:
        feats: ``[F, D']`` descriptors: a tensor, or a read-only :class:`~seqnet.core.memmaps.Spilled` map.
        frames: framewise (the seqmatch loss): ``[R, L]`` the row of ``feats`` of each window's frame
            (each frame described once); None: row ``r`` of ``feats`` is window ``r`` (F = R).
    """

    feats: torch.Tensor | np.ndarray
    frames: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.feats) if self.frames is None else len(self.frames)

    def block(self, a: int, b: int, device: torch.device) -> torch.Tensor:
        """Windows ``a:b``: ``[b - a, D']``, framewise ``[b - a, L, D']``, on ``device``."""
        if self.frames is None:
            held = isinstance(self.feats, torch.Tensor)
            return self.feats[a:b].to(device) if held else read_block(self.feats, a, b, device, torch.float32)
        idx = self.frames[a:b]
        if isinstance(self.feats, torch.Tensor):
            sub = self.feats[torch.as_tensor(idx.reshape(-1), device=self.feats.device)].to(device)
        else:
            sub = as_tensor(take_rows(self.feats, idx.reshape(-1)), device)
        return sub.reshape(*idx.shape, sub.shape[-1])

    def whole(self, device: torch.device) -> torch.Tensor:
        """Every window's descriptors, ``[R, D']`` or ``[R, L, D']`` (held in memory)."""
        return self.block(0, len(self), device)

    def step(self) -> int:
        """Windows per column block of the distances: :data:`COL_BLOCK_BYTES` of float32 descriptors."""
        per = self.feats.shape[-1] * (1 if self.frames is None else self.frames.shape[1]) * 4
        return max(1, COL_BLOCK_BYTES // per)


def as_cache(r_feat: torch.Tensor | ReferenceCache) -> ReferenceCache:
    """``r_feat``, or a tensor of the windows' descriptors ``[R, D']`` / ``[R, L, D']`` as a cache."""
    if isinstance(r_feat, ReferenceCache):
        return r_feat
    if r_feat.ndim == 3:
        r, n, d = r_feat.shape
        return ReferenceCache(r_feat.reshape(r * n, d), np.arange(r * n).reshape(r, n))
    return ReferenceCache(r_feat)


def cache_distances(distance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], q_feat: torch.Tensor,
                    cache: ReferenceCache) -> torch.Tensor:
    """``[B, R]``: ``distance`` of the queries ``q_feat [B, ...]`` to every window of ``cache``, one column
    block (:meth:`ReferenceCache.step` windows) at a time, whether the cache is held or spilled."""
    n, step = len(cache), cache.step()
    if step >= n:
        return distance(q_feat, cache.whole(q_feat.device))
    out = None
    for a in range(0, n, step):
        d = distance(q_feat, cache.block(a, min(n, a + step), q_feat.device))
        if out is None:
            out = d.new_empty((len(q_feat), n))
        out[:, a : a + d.shape[1]] = d
    return out


def closest_positive(dist: torch.Tensor, pos_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest positive of each row of ``dist [B, R]`` among ``pos_mask [B, R]``: ``(idx [B], d [B])``,
    ``idx = -1`` and ``d = inf`` where a row has no positive."""
    d, idx = dist.masked_fill(~pos_mask, float("inf")).min(dim=1)
    return torch.where(torch.isfinite(d), idx, torch.full_like(idx, -1)), d


def sample_negatives(
    neg_mask: torch.Tensor, n_sample: int, generator: torch.Generator, drawn: torch.Tensor | None = None
) -> torch.Tensor:
    """``[B, R]`` bool: a uniform random subset of each row's negatives ``neg_mask [B, R]``, of
    ``n_sample`` negatives on average (each kept with probability ``n_sample / count``; every
    negative when a row has at most ``n_sample``). Like NetVLAD's draw of ``n_sample`` with
    replacement, the number of distinct samples varies; one random number per (query, reference)
    and no sort, so it costs O(B·R). The random numbers come from ``generator`` (a CPU generator, so
    runs are reproducible anywhere). ``drawn [B']`` (bool, B true): draw the numbers of B' rows, use
    those of the marked rows (a process mining its share of a block advances the generator as all).
    """
    b, r = neg_mask.shape
    if n_sample >= r:
        return neg_mask.clone()
    keep = (n_sample / neg_mask.sum(dim=1, keepdim=True).clamp_min(1)).clamp_max(1.0)  # [B, 1]
    u = torch.rand((b if drawn is None else len(drawn), r), generator=generator)
    if drawn is not None and not bool(drawn.all()):
        u = u[drawn.cpu()]
    return neg_mask & (u.to(neg_mask.device) < keep)


def hardest_negatives(
    dist: torch.Tensor, candidates: torch.Tensor, d_pos: torch.Tensor, n_neg: int, margin: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ``n_neg`` candidates closest in descriptor space, kept where they violate the margin.

    Args:
        dist: ``[B, R]`` descriptor distances; candidates: ``[B, R]`` bool; d_pos: ``[B]``.

    Returns:
        ``(idx [B, K], valid [B, K], d [B, K])``, closest first; ``idx = -1`` where not valid.
    """
    k = min(int(n_neg), dist.shape[1])
    d, idx = torch.topk(dist.masked_fill(~candidates, float("inf")), k, dim=1, largest=False, sorted=True)
    valid = torch.isfinite(d) & (d < d_pos[:, None] + margin)
    return torch.where(valid, idx, torch.full_like(idx, -1)), valid, d


def mine_batch(
    q_feat: torch.Tensor,
    r_feat: torch.Tensor | ReferenceCache,
    pos_mask: torch.Tensor,
    neg_mask: torch.Tensor,
    n_neg: int,
    n_sample: int,
    margin: float,
    generator: torch.Generator,
    neg_cache: torch.Tensor | None = None,
    drawn: torch.Tensor | None = None,
    distance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] = pairwise_distances,
) -> Mined:
    """Mine one positive and up to ``n_neg`` hard negatives per query.

    Args:
        q_feat: ``[B, D']`` cached descriptors of the batch queries (``[B, L, D']`` for a framewise loss).
        r_feat: ``[R, D']`` cached descriptors of all training reference windows (``[R, L, D']``), or their
            :class:`ReferenceCache` (read in column blocks).
        pos_mask, neg_mask: ``[B, R]`` from :func:`~seqnet.train.truth.pair_masks`.
        n_neg: negatives per query K; n_sample: random negatives drawn per query.
        margin: triplet margin (a negative is kept only if ``d_neg < d_pos + margin``).
        generator: CPU generator for the sampling.
        neg_cache: optional ``[B, C]`` previous hard negatives per query (-1 = none), added to the sample.
        drawn: see :func:`sample_negatives` (the block these B queries are a share of).
        distance: ``[B, ...]`` × ``[R, ...]`` → ``[B, R]`` scores (the loss's ``cross``; default Euclidean).
    """
    dist = cache_distances(distance, q_feat, as_cache(r_feat))
    pos, d_pos = closest_positive(dist, pos_mask)
    cand = sample_negatives(neg_mask, n_sample, generator, drawn)
    if neg_cache is not None and neg_cache.numel():
        rows = torch.arange(cand.shape[0], device=cand.device)[:, None].expand_as(neg_cache)
        ok = neg_cache >= 0
        cand[rows[ok], neg_cache[ok]] = True
        cand &= neg_mask
    neg, valid, d_neg = hardest_negatives(dist, cand, d_pos, n_neg, margin)
    valid &= (pos >= 0)[:, None]
    neg = torch.where(valid, neg, torch.full_like(neg, -1))
    return Mined(pos, d_pos, neg, valid, d_neg)


def compute_cache(
    model: Callable[[torch.Tensor], torch.Tensor], src: TripletSource, rows: torch.Tensor, refs: slice = slice(None),
    framewise: bool = False, spill: bool = False,
) -> tuple[torch.Tensor, ReferenceCache]:
    """Current-model descriptors of the queries ``rows`` ``[S, D']`` and of the reference windows
    ``refs`` (default all), a :class:`ReferenceCache` of ``[R, D']``; ``framewise`` (the seqmatch loss):
    of every frame of those windows, ``[S, L, D']`` and a cache of each distinct frame's descriptor.

    ``spill``: on the CPU, a reference cache over :data:`~seqnet.core.memmaps.SPILL_BYTES` is written to a
    temporary file (the same numbers, read back in blocks) instead of memory.
    ``model`` maps windows ``[B, L, D]`` to descriptors ``[B, D']`` (a :class:`SeqNet` or an equivalent).
    No progress bar: this runs every ``cache_refresh`` queries inside the epoch's bar.
    """
    dev = src.device

    def describe(desc: torch.Tensor | np.ndarray, idx: np.ndarray, spill: bool) -> ReferenceCache:
        if not framewise:
            out = describe_windows(desc, idx, model, device=dev, progress=None, spill=spill)
            return ReferenceCache(out.to(dev) if isinstance(out, torch.Tensor) else out)
        frames, inverse = np.unique(idx, return_inverse=True)
        feats = describe_windows(desc, frames[:, None], model, device=dev, progress=None, spill=spill)
        return ReferenceCache(feats.to(dev) if isinstance(feats, torch.Tensor) else feats, inverse.reshape(idx.shape))

    q_feat = describe(src.q_desc, src.q_idx[rows].cpu().numpy(), False).whole(dev)  # [S, ...]
    return q_feat, describe(src.r_desc, src.r_idx[refs].cpu().numpy(), spill and dev.type == "cpu")


def mine_queries(
    src: TripletSource,
    rows: torch.Tensor,
    q_feat: torch.Tensor,
    r_feat: torch.Tensor | ReferenceCache,
    conf: MiningConfig,
    generator: torch.Generator,
    neg_cache: torch.Tensor,
    block_elems: int = 2**24,
    own: torch.Tensor | None = None,
    distance: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] = pairwise_distances,
) -> Mined:
    """Mine the triplets of the training queries ``rows [S]`` from one cache, in blocks of queries.

    ``q_feat [S, D']`` / ``r_feat [R, D']`` (or a :class:`ReferenceCache`) are the cached descriptors;
    ``conf`` gives the radii, ``n_negatives``, ``n_neg_sample`` and ``margin``. ``neg_cache [M, K]``
    (CPU, -1 = none) holds each training query's previous hard negatives and is updated for the queries that get
    triplets. Mining the queries of a cache period together is what mining them batch by batch
    gives (the cache is fixed meanwhile and each query is visited once per epoch), with a few large
    tensor operations instead of many small ones. Blocks keep ``[block, R]`` under ``block_elems``
    elements. ``own [S]`` (bool; distributed training: this process's share) mines only ``rows[own]``
    (``q_feat`` their descriptors), drawing the random numbers of every row (generators stay in step).
    ``distance``: the loss's scores of (query, reference) windows (:class:`~seqnet.train.losses.WindowLoss`).
    """
    r_feat = as_cache(r_feat)
    block = max(1, block_elems // max(1, len(r_feat)))
    parts, at = [], 0
    for s in range(0, len(rows), block):
        o = None if own is None else own[s : s + block]
        r = rows[s : s + block] if o is None else rows[s : s + block][o]
        pos_mask, neg_mask = pair_masks(src.q_pos[r], src.r_pos, conf.pos_radius, conf.neg_radius, src.pos_keys, r,
                                        src.soft_keys)
        m = mine_batch(q_feat[at : at + len(r)], r_feat, pos_mask, neg_mask, conf.n_negatives, conf.n_neg_sample,
                       conf.margin, generator, neg_cache[r.cpu()].to(q_feat.device), o, distance)
        at += len(r)
        keep = m.has_triplet
        neg_cache[r[keep].cpu()] = m.negatives[keep].cpu()
        parts.append(m)
    return Mined.cat(parts)
