"""Benchmark one SeqNet training epoch: seqnet's batched step vs the original code's per-triplet loops.

Both train the same model on the same data (the train split of a synthetic dataset) with the same
epoch structure (shuffled queries; mining descriptors recomputed every ``cache_refresh`` queries;
batches of 16 queries, 10 hard negatives each among ``n_neg_sample`` sampled):

* ``batched`` — :func:`seqnet.train.epoch.train_epoch`: the triplets of all queries of a cache period
  mined at once (``[S, R]`` distance matrix and masks), then per batch one forward pass (SeqNet in
  its one-GEMM form) and one triplet loss over all the batch's triplets;
* ``loop`` — the original seqNet/NetVLAD way: the mining cache built in batches of 24 windows, then
  per query a faiss index over its positives and over its sampled negatives (plus its negative
  cache), windows gathered per negative, the model's Conv1d forward, and the loss summed over a
  Python loop of one ``nn.TripletMarginLoss`` call per (query, positive, negative) triplet
  (``--loop-forward gemm`` gives the loop seqnet's forward, to isolate the cost of the loops).

A check runs the first batch of both from the same model with every negative sampled: both mine the
same triplets, so the losses must agree, which shows the loop is the same step. Target:
``loop / batched >= 10`` per epoch on CPU. Both wall-clock and process CPU time are reported (CPU
time is much less disturbed by other jobs on a shared machine). One torch thread by default: the
tensors are small, and on a shared machine extra OpenMP threads mostly measure contention.

Usage::

    python benchmarks/bench_train.py                   # defaults: 1000 places, D = 64, 1 thread
    python benchmarks/bench_train.py --threads 2 --dim 256 --json out.json --check
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import faiss
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from seqnet.data.synth import make_synthetic
from seqnet.train import Run, TrainConfig
from seqnet.train.epoch import train_epoch, train_step
from seqnet.train.mining import mine_queries
from seqnet.train.run import open_run
from seqnet.train.source import triplet_source

TARGET = 10.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--places", type=int, default=1000, help="synthetic route length (default 1000)")
    p.add_argument("--dim", type=int, default=64, help="descriptor dimension D (default 64)")
    p.add_argument("--seq-len", type=int, default=5, help="sequence length L (default 5)")
    p.add_argument("--w", type=int, default=3, help="SeqNet filter width (default 3)")
    p.add_argument("--n-neg-sample", type=int, default=1000, help="negatives sampled per query (default 1000)")
    p.add_argument("--loop-forward", choices=["conv", "gemm"], default="conv",
                   help="forward pass of the loop: the model's Conv1d as the original (default) or seqnet's GEMM form "
                        "(isolates the cost of the loops)")
    p.add_argument("--repeats", type=int, default=5, help="epochs timed per implementation; best kept (default 5)")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    p.add_argument("--check", action="store_true", help="exit with status 1 when the target is missed")
    return p.parse_args(argv)


class LoopTrainer:
    """The original code's training step (datasets.py ``__getitem__`` + train.py loop), on a Run."""

    def __init__(self, run: Run, src, conf: TrainConfig, exhaustive: bool = False, forward: str = "conv") -> None:
        self.run, self.src, self.cfg, self.exhaustive = run, src, conf.to_dict(), exhaustive
        cfg = self.cfg
        self.forward = run.model.forward_conv if forward == "conv" else run.model
        q_pos, r_pos = src.q_pos.numpy(), src.r_pos.numpy()
        tree = cKDTree(r_pos)
        self.positives = [np.sort(p) for p in tree.query_ball_point(q_pos, cfg["pos_radius"])]
        near = tree.query_ball_point(q_pos, cfg["neg_radius"])
        self.negatives = [np.setdiff1d(np.arange(len(r_pos)), n, assume_unique=True) for n in near]
        self.neg_cache = [np.empty((0,), dtype=np.int64) for _ in range(src.n_queries)]
        self.q_desc, self.r_desc = src.q_desc.numpy(), src.r_desc.numpy()
        self.q_idx, self.r_idx = src.q_idx.numpy(), src.r_idx.numpy()
        self.rng = np.random.default_rng(cfg["seed"])
        self.criterion = nn.TripletMarginLoss(margin=cfg["margin"], p=2, reduction="sum")

    def cache(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Descriptors of all reference windows and of the queries ``rows``, 24 windows per batch."""
        out = []
        with torch.no_grad():
            for desc, idx in ((self.r_desc, self.r_idx), (self.q_desc, self.q_idx[rows])):
                batches = (torch.from_numpy(desc[idx[s : s + 24]]) for s in range(0, len(idx), 24))
                feats = [self.forward(x).numpy() for x in batches]
                out.append(np.concatenate(feats))
        return out[1], out[0]

    def get_item(self, i: int, q_feat: np.ndarray, r_feat: np.ndarray):
        pos = self.positives[i]
        index = faiss.IndexFlatL2(r_feat.shape[1])
        index.add(r_feat[pos])
        d_pos, pos_nn = index.search(q_feat[None], 1)
        d_pos, pos_index = float(np.sqrt(d_pos[0, -1])), pos[pos_nn[0, -1]]
        sample = self.negatives[i] if self.exhaustive else self.rng.choice(self.negatives[i], self.cfg["n_neg_sample"])
        sample = np.sort(np.unique(np.concatenate([self.neg_cache[i], sample]))).astype(np.int64)
        index = faiss.IndexFlatL2(r_feat.shape[1])
        index.add(r_feat[sample])
        d_neg, neg_nn = index.search(q_feat[None], self.cfg["n_negatives"] * 10)
        d_neg, neg_nn = np.sqrt(d_neg.reshape(-1)), neg_nn.reshape(-1)
        violating = (d_neg < d_pos + self.cfg["margin"]) & (neg_nn >= 0)
        if violating.sum() < 1:
            return None
        neg_idx = sample[neg_nn[violating][: self.cfg["n_negatives"]]]
        self.neg_cache[i] = neg_idx
        query = torch.from_numpy(self.q_desc[self.q_idx[i]])
        positive = torch.from_numpy(self.r_desc[self.r_idx[pos_index]])
        negatives = torch.stack([torch.tensor(self.r_desc[self.r_idx[n]]) for n in neg_idx])
        return query, positive, negatives

    def step(self, rows: np.ndarray, q_feat: np.ndarray, r_feat: np.ndarray) -> float:
        batch = [b for b in (self.get_item(int(i), q_feat[k], r_feat) for k, i in enumerate(rows)) if b is not None]
        if not batch:
            return math.nan
        query, positive, negatives = zip(*batch, strict=True)
        counts = [n.shape[0] for n in negatives]
        b, n_neg = len(batch), sum(counts)
        emb = self.forward(torch.cat([torch.stack(query), torch.stack(positive), torch.cat(negatives)]))  # L2-normed
        e_q, e_p, e_n = torch.split(emb, [b, b, n_neg])
        self.run.optimizer.zero_grad()
        loss = 0
        for i, count in enumerate(counts):
            for n in range(count):
                neg_ix = sum(counts[:i]) + n
                loss += self.criterion(e_q[i : i + 1], e_p[i : i + 1], e_n[neg_ix : neg_ix + 1])
        loss /= n_neg
        loss.backward()
        self.run.optimizer.step()
        return float(loss.detach())

    def epoch(self) -> None:
        n, bs, chunk = self.src.n_queries, self.cfg["batch_size"], self.cfg["cache_refresh"] or self.src.n_queries
        order = self.rng.permutation(n)
        for s in range(0, n, chunk):
            sub = order[s : s + chunk]
            q_feat, r_feat = self.cache(sub)
            for b in range(0, len(sub), bs):
                self.step(sub[b : b + bs], q_feat[b : b + bs], r_feat)


def setup(args: argparse.Namespace, out_dir: Path):
    ds = make_synthetic(places=args.places, dim=args.dim, seed=args.seed)
    conf = TrainConfig(seq_len=args.seq_len, w=args.w, n_neg_sample=args.n_neg_sample, device="cpu",
                       seed=args.seed).resolve(ds)
    src = triplet_source(ds.split("train"), conf.seq_len, conf.window, conf.mining, torch.device("cpu"))
    return conf, src, open_run(conf, src.n_queries, ds.query.dim, torch.device("cpu"), out_dir)


def same_step_check(args: argparse.Namespace, tmp: Path) -> tuple[float, float]:
    """Loss of the first batch by both implementations, from the same model (exhaustive sampling)."""
    conf, src, run = setup(args, tmp / "check")
    rows = torch.arange(min(conf.batch_size, src.n_queries))
    loop = LoopTrainer(run, src, conf, exhaustive=True)
    mining = conf.mining.replace(n_neg_sample=len(src.r_idx))  # every negative, as the exhaustive loop
    q_feat, r_feat = loop.cache(rows.numpy())
    state = {k: v.clone() for k, v in run.model.state_dict().items()}
    loop_loss = loop.step(rows.numpy(), q_feat, r_feat)
    run.model.load_state_dict(state)
    mined = mine_queries(src, rows, torch.from_numpy(q_feat), torch.from_numpy(r_feat), mining, run.generator,
                         run.neg_cache)
    batched = train_step(run, src, rows, mined)["loss"]
    run.close()
    return batched, loop_loss


def time_epochs(args: argparse.Namespace, tmp: Path) -> dict[str, dict[str, float]]:
    """Best-of-``repeats`` wall-clock and process CPU seconds of one epoch of each implementation.

    CPU time (``time.process_time``) is what the epoch costs; on a shared machine it is much less
    disturbed by other jobs than wall-clock time, which is what one waits.
    """
    wall: dict[str, list[float]] = {"batched": [], "loop": []}
    cpu: dict[str, list[float]] = {"batched": [], "loop": []}
    for rep in range(args.repeats):
        for name in ("batched", "loop"):
            conf, src, run = setup(args, tmp / f"{name}{rep}")
            loop = LoopTrainer(run, src, conf, forward=args.loop_forward) if name == "loop" else None
            t0, c0 = time.perf_counter(), time.process_time()
            loop.epoch() if loop is not None else train_epoch(run, src, 1)
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
            run.close()
    return {"wall": {k: min(v) for k, v in wall.items()}, "cpu": {k: min(v) for k, v in cpu.items()},
            "sizes": {"queries": src.n_queries, "references": len(src.r_idx)}}


def main(argv: list[str] | None = None) -> int:
    import tempfile

    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    faiss.omp_set_num_threads(args.threads)
    with tempfile.TemporaryDirectory(prefix="bench-train-") as d:
        batched_loss, loop_loss = same_step_check(args, Path(d))
        t = time_epochs(args, Path(d))
    ratio = {k: t[k]["loop"] / t[k]["batched"] for k in ("wall", "cpu")}
    res = {"places": args.places, "dim": args.dim, "loop_forward": args.loop_forward, "seq_len": args.seq_len,
           "w": args.w, "threads": args.threads,
           "n_neg_sample": args.n_neg_sample, "train_queries": t["sizes"]["queries"],
           "reference_windows": t["sizes"]["references"],
           "first_batch_loss": {"batched": batched_loss, "loop": loop_loss},
           "epoch_wall_s": t["wall"], "epoch_cpu_s": t["cpu"], "ratio_wall": ratio["wall"], "ratio_cpu": ratio["cpu"],
           "target": TARGET, "torch": torch.__version__, "machine": platform.machine(), "load_avg": os.getloadavg()}
    print(f"train split: {res['train_queries']} queries, {res['reference_windows']} reference windows; D={args.dim}, "
          f"L={args.seq_len}, w={args.w}, {args.threads} threads; load average {res['load_avg'][0]:.1f}")
    print(f"first-batch loss: batched {batched_loss:.6f}, loop {loop_loss:.6f}")
    for k, what in (("wall", "wall-clock"), ("cpu", "CPU time")):
        print(f"epoch {what}: batched {t[k]['batched']:.3f} s, per-triplet loop {t[k]['loop']:.3f} s -> "
              f"{ratio[k]:.1f}x (target >= {TARGET:g}x)")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    same = math.isclose(batched_loss, loop_loss, rel_tol=1e-3)
    if not same:
        print("error: the two implementations disagree on the first batch", file=sys.stderr)
    return 1 if args.check and (ratio["wall"] < TARGET or not same) else 0


if __name__ == "__main__":
    sys.exit(main())
