"""One training epoch: mining the triplets of each cache period and one optimiser step per batch.

Every ``cache_refresh`` queries of the shuffled order the mining descriptors are recomputed by the
current model and those queries' triplets mined (:mod:`seqnet.train.mining`); then one step per
batch of ``batch_size`` queries over all the batch's triplets (:func:`train_step`).

Distributed training (:mod:`seqnet.train.distributed`): every process draws the same order; each
batch is split across the processes (contiguous shares), each mines and computes the loss of its
share, the loss is its part of the batch mean (divided by the whole batch's triplet count) and
DistributedDataParallel sums the gradients, so the update is the single-process update of the same
batch up to float rounding. With one process every helper is the identity (the same numbers).
"""

from __future__ import annotations

import math

from ..core.lazy import lazy_module
from ..core.progress import progress
from .losses import LOSSES, describe_pair, triplet_loss
from .mining import Mined, compute_cache, mine_queries
from .run import Run
from .source import TripletSource, source_windows, speed_source

torch = lazy_module("torch")

STAT_KEYS = ("loss", "queries", "skipped", "triplets", "active")


def train_step(run: Run, src: TripletSource, rows: torch.Tensor, mined: Mined,
               total: int | None = None) -> dict[str, float]:
    """One optimiser step on all triplets of the queries ``rows [B]`` (``mined``: their triplets).

    ``total``: the triplets of the whole batch when ``rows`` is this process's share of it (default:
    those of ``rows``); the loss is then this share's part of the batch mean (a sum over the shares),
    and a batch without any triplet (on every rank) makes no step."""
    keep = mined.has_triplet
    b = int(keep.sum())
    valid = mined.valid[keep]
    t = int(valid.sum())
    stats = {"queries": float(b), "skipped": float(len(rows) - b), "triplets": float(t), "active": 0.0, "loss": 0.0}
    if (t if total is None else total) == 0:
        return stats
    ref = torch.cat([mined.positive[keep], mined.negatives[keep][valid]])
    loss = LOSSES[run.conf.loss]
    q_win, r_win = source_windows(src.q_desc, src.q_idx[rows[keep]]), source_windows(src.r_desc, src.r_idx[ref])
    q_emb, r_emb = describe_pair(loss, run.model if run.net is None else run.net, q_win, r_win)  # r: p then n
    out = triplet_loss(q_emb, r_emb[:b], r_emb[b:], valid.nonzero()[:, 0], run.conf.margin, total, loss.pair)
    run.optimizer.zero_grad(set_to_none=True)
    out.loss.backward()  # distributed: DDP sums the gradients of the shares
    run.optimizer.step()
    stats.update(active=float(out.active), loss=float(out.loss.detach()))
    return stats


def mine_share(run: Run, src: TripletSource, rows: torch.Tensor, own: torch.Tensor) -> tuple[Mined, torch.Tensor]:
    """Refresh the mining cache and mine this process's queries ``rows[own]`` (``rows [S]``, ``own [S]``
    bool): returns their triplets and the triplet count of every query of ``rows`` (all processes'),
    and updates the negative cache of all of ``rows`` (the same on every process). Each process
    describes its :meth:`~seqnet.train.distributed.World.part` of the reference windows (all-gathered)."""
    world, mine = run.world, rows[own]
    refs = world.part(len(src.r_idx))
    loss = LOSSES[run.conf.loss]
    q_feat, r_part = compute_cache(run.model, src, mine, refs, loss.framewise, spill=world.size == 1)
    r_feat = r_part if world.size == 1 else world.gather_rows(r_part.whole(src.device), len(src.r_idx))
    mined = mine_queries(src, rows, q_feat, r_feat, run.conf.mining, run.generator, run.neg_cache, own=own,
                         distance=loss.cross)
    counts = mined.valid.sum(dim=1, keepdim=True).cpu()
    merged = world.merge_rows(own.cpu(), torch.cat([counts, run.neg_cache[mine.cpu()]], dim=1))
    run.neg_cache[rows.cpu()] = merged[:, 1:]
    return mined, merged[:, 0]


def train_epoch(run: Run, src: TripletSource, epoch: int) -> dict[str, float]:
    """One pass over every training query (shuffled); every ``cache_refresh`` queries the mining
    descriptors are recomputed and those queries' triplets mined. Returns the mean batch loss and
    summed counts (queries, skipped, triplets, active). One progress bar, with loss / active.

    Distributed: every process draws the same order; each batch of ``batch_size`` queries is split
    across the processes (:meth:`~seqnet.train.distributed.World.shares`), each mining and computing
    the loss of its share; the statistics are summed over the processes."""
    n, bs, world, conf = src.n_queries, run.conf.batch_size, run.world, run.conf
    src = speed_source(src, conf.window_len, conf.window, conf.speed_augment, run.generator)
    order = torch.randperm(n, generator=run.generator).to(src.q_idx.device)
    chunk = run.conf.mining.cache_refresh or n
    totals = dict.fromkeys(STAT_KEYS, 0.0)
    steps = 0
    n_batches = sum(math.ceil(min(chunk, n - s) / bs) for s in range(0, n, chunk))
    with progress(total=n_batches, desc=f"epoch {epoch}/{run.conf.epochs}", unit="batch") as bar:
        for s in range(0, n, chunk):
            sub = order[s : s + chunk]
            own = world.shares(len(sub), bs).to(sub.device)
            mined, counts = mine_share(run, src, sub, own)
            at = 0
            for b in range(0, len(sub), bs):
                mine = own[b : b + bs]
                k = int(mine.sum())
                st = train_step(run, src, sub[b : b + bs][mine], mined[at : at + k], int(counts[b : b + bs].sum()))
                st, at = world.sum_stats(st), at + k
                steps += st["triplets"] > 0
                totals = {key: v + st[key] for key, v in totals.items()}
                bar.update(1)
                if not bar.disable:
                    bar.set_postfix(loss=f"{st['loss']:.4f}", active=int(st["active"]), refresh=False)
    totals["loss"] /= max(steps, 1)
    return totals
