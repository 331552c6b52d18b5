"""The peer's way of single-image k-NN retrieval, written for benchmarks/peers.py (not seqnet code).

What VPR-methods-evaluation does after describing: a faiss ``IndexFlatL2`` over the database descriptors,
one ``search`` of every query for the largest K, then Recall@K against the positives within the radius.
Reads a seqnet dataset directory's ``reference/`` and ``query/`` descriptors and frame positions, prints
one JSON line ``{"recall@1": ..., ...}``.

Usage::

    python benchmarks/peer_faiss_knn.py DATASET_DIR [--ks 1,5,10,20] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import sys

import faiss
import numpy as np


def nearest_gap(db_pos: np.ndarray, q_pos: np.ndarray) -> np.ndarray:
    """``[Nq]``: distance from each query frame position to the nearest database frame position (1-D)."""
    srt = np.sort(db_pos)
    j = np.clip(np.searchsorted(srt, q_pos), 1, len(srt) - 1) if len(srt) > 1 else np.zeros(len(q_pos), int)
    return np.minimum(np.abs(srt[j] - q_pos), np.abs(srt[j - 1] - q_pos))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dataset")
    p.add_argument("--ks", default="1,5,10,20")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    faiss.omp_set_num_threads(args.threads)
    ks = [int(k) for k in args.ks.split(",")]
    with open(f"{args.dataset}/dataset.json") as f:
        radius = float(json.load(f)["radius"])
    db = np.load(f"{args.dataset}/reference/descriptors.npy")
    q = np.load(f"{args.dataset}/query/descriptors.npy")
    db_pos = np.load(f"{args.dataset}/reference/positions.npy")[:, 0]
    q_pos = np.load(f"{args.dataset}/query/positions.npy")[:, 0]
    index = faiss.IndexFlatL2(db.shape[1])
    index.add(db)
    _, preds = index.search(q, max(ks))
    correct = np.abs(db_pos[preds] - q_pos[:, None]) <= radius  # [Nq, K]
    has_positive = nearest_gap(db_pos, q_pos) <= radius
    hits = np.cumsum(correct, axis=1) > 0
    out = {f"recall@{k}": float(hits[has_positive, k - 1].mean()) for k in ks}
    out["queries"] = int(has_positive.sum())
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
