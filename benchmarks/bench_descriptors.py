"""Single-image descriptors on Nordland64: Recall@1 (single, raw+SeqMatch L=5) and extraction speed.

Usage::

    python benchmarks/bench_descriptors.py [--configs pixels,gem,gmp,netvlad] [--size 256x128]
        [--threads 2] [--json results.json]

Data: ``$SEQNET_SHARED_DATA/nordland64`` (default ``../shared/data/nordland64`` beside the repo):
summer/ and winter/ 64×32 PNG frames and ``nordland_clean_imageNames.txt``. Test range: indices
1940:2761 of the clean frames present (names ending in '0', sorted by frame number); reference =
summer, query = winter, position = frame number / 10, radius 1. PCA and NetVLAD clusters are fitted
on training frames only (clean indices 0:1940 of both seasons, evenly spaced), never on the test
range. Speed = test images (reference + query) / seconds, PNG decoding and resizing included,
fitting excluded. Exits 0 with a message when the data is absent.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

import numpy as np
import torch

from seqnet.data.traverse import Dataset, Traverse
from seqnet.describe import DescribeConfig, make_describer
from seqnet.eval.evaluate import EvalConfig, evaluate

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("SEQNET_SHARED_DATA", REPO.parent / "shared" / "data")) / "nordland64"
TEST = (1940, 2761)
N_FIT = 250  # training frames per season used to fit PCA / NetVLAD clusters

# name -> (method, options); the others run on frames upscaled to --size
CONFIGS = {
    "pixels": ("pixels", {"size": "native"}),
    "gem": ("gem", {}),
    "gmp": ("gmp", {}),
    "netvlad": ("netvlad", {"clusters": 64}),  # EfficientNet-Lite0 block 10, K=64: 7168-D
    "netvlad+pcaw": ("netvlad", {"clusters": 64, "dim": 256, "whiten": True}),
    "gem+pcaw": ("gem", {"dim": 256, "whiten": True}),
    "gem-b10": ("gem", {"layer": 10}),  # GeM of the stride-16 block-10 map instead of the head
}


def frame_number(name: str) -> int:
    return int(re.findall(r"\d+", name)[-1])


def clean_frames(root: Path) -> list[str]:
    """Clean frame names ending in '0' present in both seasons, sorted by frame number."""
    names = (root / "nordland_clean_imageNames.txt").read_text().split()
    have = set(os.listdir(root / "summer")) & set(os.listdir(root / "winter"))
    return sorted({n for n in names if Path(n).stem.endswith("0") and n in have}, key=frame_number)


def run_config(name: str, frames: list[str], size: tuple[int, int], batch: int) -> dict:
    """R@1 (single, raw+seqmatch), dim, fitting seconds and images/s of one configuration."""
    method, opts = CONFIGS[name]
    train = frames[: TEST[0]]
    fit = [DATA / s / n for n in train[:: max(1, len(train) // N_FIT)] for s in ("summer", "winter")]
    conf = DescribeConfig(method=method, batch_size=batch, fit=fit, size=size).replace(**opts)
    t0 = time.perf_counter()
    describer = make_describer(conf)
    fit_s = time.perf_counter() - t0
    test = frames[TEST[0] : TEST[1]]
    t0, c0 = time.perf_counter(), time.process_time()
    ref, _ = describer.describe([DATA / "summer" / n for n in test])
    qry, _ = describer.describe([DATA / "winter" / n for n in test])
    speed = 2 * len(test) / (time.perf_counter() - t0)
    cpu_ms = (time.process_time() - c0) * 1e3 / (2 * len(test))
    pos = np.array([frame_number(n) / 10 for n in test])
    ds = Dataset(Traverse(ref, pos, name="summer"), Traverse(qry, pos, name="winter"), radius=1.0,
                 position_unit="frames", name="nordland64-test")
    res = evaluate(ds, EvalConfig(methods=("single", "raw+seqmatch"), seq_len=5)).results["methods"]
    used = describer.config.size
    return {"method": method, "size": "native 64x32" if used == "native" else f"{used[0]}x{used[1]}",
            "dim": int(ref.shape[1]), "single_r1": res["single"]["recall@1"],
            "seqmatch_r1": res["raw+seqmatch"]["recall@1"], "queries": res["single"]["queries"],
            "images_per_s": round(speed, 1), "cpu_ms_per_image": round(cpu_ms, 2), "fit_s": round(fit_s, 1)}


def markdown(rows: dict[str, dict]) -> str:
    head = ("| descriptor | input | D | single R@1 | raw+SeqMatch R@1 (L=5) | images/s | CPU ms/image | fit s |\n"
            "|---|---|---|---|---|---|---|---|")
    lines = [f"| {k} | {r['size']} | {r['dim']} | {r['single_r1']:.3f} | {r['seqmatch_r1']:.3f} | "
             f"{r['images_per_s']:.0f} | {r['cpu_ms_per_image']:.1f} | {r['fit_s']:.0f} |" for k, r in rows.items()]
    return "\n".join([head, *lines])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--configs", default="pixels,gem,gmp,netvlad", help=f"comma-separated of {', '.join(CONFIGS)}")
    ap.add_argument("--size", default="256x128", help="CNN input size WxH (default 256x128)")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", help="write the results as JSON")
    args = ap.parse_args()
    if not (DATA / "nordland_clean_imageNames.txt").is_file():
        print(f"skipped: Nordland64 data not found at {DATA} (set SEQNET_SHARED_DATA)")
        return 0
    torch.set_num_threads(args.threads)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    frames = clean_frames(DATA)
    print(f"{len(frames)} clean frames; test {TEST[0]}:{TEST[1]} ({TEST[1] - TEST[0]} per season), "
          f"{args.threads} threads", flush=True)
    rows = {}
    for name in args.configs.split(","):
        if name not in CONFIGS:
            sys.exit(f"unknown config {name!r}; valid: {', '.join(CONFIGS)}")
        rows[name] = run_config(name, frames, size, args.batch_size)
        print(json.dumps({name: rows[name]}), flush=True)
    print(markdown(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
