"""Write the online-latency case of ``bench_localize.py`` as files, to time it through the command a user types.

Usage::

    python benchmarks/write_localize_dataset.py OUT [--frames 14000] [--dim 4096] [--queries 300] [--w 5]
    seqnet localize --dataset OUT/dataset --model OUT/sl.pt --model OUT/s1.pt --method hvpr --seq-len 5 \\
        --split all --out OUT/track.csv

The map is ``bench_localize.synthetic_map`` (random unit vectors, neighbours correlated); the queries are a
stretch of it plus noise; the checkpoints are untrained SeqNets of the benchmark's sizes (S_L: L = 5, kernel
``w``, D → D; S_1: D → D): a step's cost does not depend on the weights. One step reads the S_1 and S_L weights
and the map's S_L items once (632 MB in float32 at the defaults): compare the printed median with those bytes
over the copy bandwidth ``bench_localize.bandwidth()`` measures.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from bench_localize import synthetic_map

from seqnet.data.io import save_dataset
from seqnet.data.traverse import Dataset, Traverse
from seqnet.sequence.checkpoints import save_checkpoint
from seqnet.sequence.model import SeqNet


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out")
    p.add_argument("--frames", type=int, default=14000)
    p.add_argument("--dim", type=int, default=4096)
    p.add_argument("--queries", type=int, default=300)
    p.add_argument("--w", type=int, default=5)
    args = p.parse_args()
    out = Path(args.out)
    ref = synthetic_map(args.frames, args.dim)
    start = args.frames // 3
    rng = np.random.default_rng(1)
    q = ref[start : start + args.queries] + 0.02 * rng.standard_normal((args.queries, args.dim), dtype=np.float32)
    ds = Dataset(Traverse(ref, np.arange(args.frames, dtype=np.float64)[:, None]),
                 Traverse(q, np.arange(start, start + args.queries, dtype=np.float64)[:, None]), 1.0, name="latency")
    save_dataset(ds, out / "dataset", overwrite=True)
    torch.manual_seed(0)
    save_checkpoint(out / "sl.pt", SeqNet(args.dim, args.dim, 5, args.w))
    save_checkpoint(out / "s1.pt", SeqNet(args.dim, args.dim, 1, 1))
    print(f"wrote {out}/dataset, {out}/sl.pt, {out}/s1.pt")


if __name__ == "__main__":
    main()
