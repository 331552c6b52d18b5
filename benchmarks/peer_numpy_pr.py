"""The peer's way of evaluating a given similarity matrix, written for benchmarks/peers.py (not seqnet code).

What VPR_Tutorial does with a similarity matrix ``S [N_db, N_q]``: the best match of every query
(``argmax`` over the database), Recall@1 against the ground truth, and a precision-recall curve over
thresholds on the best matches' similarities (its AUC printed). Ground truth: database frames within the
radius of the query's frame position (a seqnet dataset directory's positions). Prints one JSON line.

Usage::

    python benchmarks/peer_numpy_pr.py DATASET_DIR S.npy
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def nearest_gap(db_pos: np.ndarray, q_pos: np.ndarray) -> np.ndarray:
    """``[Nq]``: distance from each query frame position to the nearest database frame position (1-D)."""
    srt = np.sort(db_pos)
    j = np.clip(np.searchsorted(srt, q_pos), 1, len(srt) - 1) if len(srt) > 1 else np.zeros(len(q_pos), int)
    return np.minimum(np.abs(srt[j] - q_pos), np.abs(srt[j - 1] - q_pos))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dataset")
    p.add_argument("matrix")
    args = p.parse_args(argv)
    with open(f"{args.dataset}/dataset.json") as f:
        radius = float(json.load(f)["radius"])
    db_pos = np.load(f"{args.dataset}/reference/positions.npy")[:, 0]
    q_pos = np.load(f"{args.dataset}/query/positions.npy")[:, 0]
    s = np.load(args.matrix)  # [N_db, N_q] similarities
    best = np.argmax(s, axis=0)
    score = s[best, np.arange(s.shape[1])]
    correct = np.abs(db_pos[best] - q_pos) <= radius
    has_positive = nearest_gap(db_pos, q_pos) <= radius
    order = np.argsort(-score, kind="stable")  # thresholds from the most similar match down
    tp = np.cumsum(correct[order])
    precision = tp / np.arange(1, len(order) + 1)
    recall = tp / max(1, int(has_positive.sum()))
    auc = float(np.trapezoid(precision, recall)) if len(order) > 1 else 0.0
    print(json.dumps({"recall@1": float(correct[has_positive].mean()), "auc": auc,
                      "queries": int(has_positive.sum())}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
