"""Peak memory of each user command on a large map: is every one bounded by the map's bytes + 512 MiB?

Writes a synthetic dataset (a smooth route of N_db reference frames of D dimensions, and a query
traverse that revisits a stretch of it with noise) to a temporary folder, then runs the commands a
user types, each in a child process whose peak resident set size is read from ``os.wait4``
(``ru_maxrss``: anonymous memory *and* the resident pages of memory-mapped files):

* ``eval --dataset`` with single-image k-NN, whole-map SeqMatch and a sequence shortlist
  (the "map" is the dataset's reference descriptor file);
* ``index build`` (smoothing shortlist, raw frames + SeqMatch, exact ``flat`` index), then
  ``eval --index`` and ``localize --map`` on that map (the "map" is the map folder);
* ``train`` for one epoch on the whole dataset without validation (S_1 by default: the mining cache
  of every reference window is the same ``[N_db, D]`` as S_L's, the model a third of its weights;
  ``--train-seq-len 5 --train-w 3`` trains S_L); the "map" is the reference and query descriptor files;
* ``describe`` of a folder of ``--images`` greyscale PNGs of ``sqrt(D) x sqrt(D)`` pixels with the
  ``pixels`` describer (D = H·W), and ``dataset from-images`` of that folder and a query folder of
  ``--query-images`` (query i at reference i: explicit positives); the "map" is the descriptors the command
  writes.

Usage::

    python benchmarks/bench_map_rss.py --n-db 100000 --dim 4096 --out OUT/rss
    python benchmarks/bench_map_rss.py --n-db 100000 --dim 4096 --images 100000 \
        --commands train,describe,from-images --out OUT/rss-more
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BUDGET = 512 * 2**20


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-db", type=int, default=100000)
    p.add_argument("--dim", type=int, default=4096)
    p.add_argument("--queries", type=int, default=1000, help="query frames (a stretch of the route revisited)")
    p.add_argument("--localize-frames", type=int, default=200, help="query frames streamed by localize --map")
    p.add_argument("--noise", type=float, default=1.0)
    p.add_argument("--dtype", default="float32", choices=("float32", "float16"))
    p.add_argument("--commands", default=",".join(COMMANDS), help=f"which of {', '.join(COMMANDS)}")
    p.add_argument("--images", type=int, default=2000, help="images described by describe / from-images")
    p.add_argument("--query-images", type=int, default=200, help="query images of from-images")
    p.add_argument("--train-seq-len", type=int, default=1, help="train: --seq-len (1: S_1)")
    p.add_argument("--train-w", type=int, default=1, help="train: --w")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", required=True)
    p.add_argument("--make-dataset", help=argparse.SUPPRESS)  # internal: write the dataset into this folder
    return p.parse_args(argv)


def make_images(args: argparse.Namespace, root: Path) -> None:
    """Write ``args.images`` greyscale PNGs of ``sqrt(D) x sqrt(D)`` pixels to ``root/img-ref`` and
    ``args.query_images`` noisy copies of the first ones to ``root/img-qry``."""
    from PIL import Image

    side = math.isqrt(args.dim)
    if side * side != args.dim:
        raise SystemExit(f"describe / from-images need a square --dim (the pixels of an image), got {args.dim}")
    rng = np.random.default_rng(1)
    for name, n in (("img-ref", args.images), ("img-qry", args.query_images)):
        (root / name).mkdir()
        for i in range(n):
            img = np.random.default_rng(i).integers(0, 256, (side, side), dtype=np.uint8)
            if name == "img-qry":
                img = np.clip(img + rng.normal(0, 20, img.shape), 0, 255).astype(np.uint8)
            Image.fromarray(img, "L").save(root / name / f"{i:07d}.png")
    # query i shows the place of reference i; the reference runs on, so the traverses are not frame-aligned
    pairs = "".join(f"{i},{i}\n" for i in range(args.query_images))
    (root / "img-positives.csv").write_text("query,reference\n" + pairs)


def make_dataset(args: argparse.Namespace, root: Path) -> Path:
    """Write the synthetic dataset to ``root/ds`` (run in a child process: see :func:`main`)."""
    from seqnet.core.provenance import make as make_provenance
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.pipelines.timing.synth import route

    rng = np.random.default_rng(0)
    frames = route(args.n_db, args.dim, rng)
    s0 = int(rng.integers(0, args.n_db - args.queries))
    q = frames[s0 : s0 + args.queries] * np.sqrt(args.dim)
    q = q + args.noise * rng.standard_normal(q.shape).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    prov = make_provenance("synthetic", {"generator": "bench_map_rss", "dim": args.dim}, dim=args.dim)
    ref = Traverse(frames, np.arange(args.n_db, dtype=np.float64), provenance=prov, name="reference")
    qry = Traverse(q.astype(np.float32), np.arange(s0, s0 + args.queries, dtype=np.float64), provenance=prov,
                   name="query")
    return save_dataset(Dataset(ref, qry, radius=2.0, name=f"route-{args.n_db}x{args.dim}"), root / "ds")


def run_measured(cmd: list[str], env: dict[str, str]) -> tuple[int, float, int, str]:
    """Run ``cmd``; return its exit code, seconds, peak RSS in bytes (``ru_maxrss`` of the child) and output."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        log.seek(0)
        out = log.read().decode(errors="replace")
    return os.waitstatus_to_exitcode(status), time.perf_counter() - t0, usage.ru_maxrss * 1024, out


def tree_bytes(path: Path | list[Path]) -> int:
    if isinstance(path, list):
        return sum(tree_bytes(p) for p in path)
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else path.stat().st_size


def eval_dataset(method: str):
    def argv(tmp: Path, args: argparse.Namespace) -> tuple[list[str], Path]:
        return ["eval", "--dataset", str(tmp / "ds"), "--split", "all", "--method", method, "--seq-len", "5",
                "--json", str(tmp / f"eval-{method}.json")], tmp / "ds" / "reference" / "descriptors.npy"
    return argv


def index_build(tmp: Path, args: argparse.Namespace) -> tuple[list[str], Path]:
    return ["index", "build", "--dataset", str(tmp / "ds"), "--split", "all", "--shortlist", "smoothing",
            "--rerank", "raw+seqmatch", "--index", "flat", "--window", "causal", "--dtype", args.dtype,
            "--out", str(tmp / "map")], tmp / "ds" / "reference" / "descriptors.npy"


def eval_index(tmp: Path, args: argparse.Namespace) -> tuple[list[str], Path]:
    return ["eval", "--dataset", str(tmp / "ds"), "--split", "all", "--index", str(tmp / "map"), "--window",
            "causal", "--json", str(tmp / "eval-index.json")], tmp / "map"


def localize_map(tmp: Path, args: argparse.Namespace) -> tuple[list[str], Path]:
    q = np.load(tmp / "ds" / "query" / "descriptors.npy", mmap_mode="r")[: args.localize_frames]
    np.save(tmp / "stream.npy", np.ascontiguousarray(q))
    return ["localize", "--map", str(tmp / "map"), "--query", str(tmp / "stream.npy"), "--method",
            "hvpr-smoothing:raw+seqmatch", "--out", str(tmp / "track.csv")], tmp / "map"


def train(tmp: Path, args: argparse.Namespace) -> tuple[list[str], list[Path]]:
    return ["train", "--dataset", str(tmp / "ds"), "--out", str(tmp / "run"), "--seq-len", str(args.train_seq_len),
            "--w", str(args.train_w), "--epochs", "1", "--train-split", "all", "--val-split", "none",
            "--cache-refresh", "0", "--device", "cpu"], \
        [tmp / "ds" / s / "descriptors.npy" for s in ("reference", "query")]


def describe(tmp: Path, args: argparse.Namespace) -> tuple[list[str], Path]:
    return ["describe", str(tmp / "img-ref"), "--method", "pixels", "--out", str(tmp / "desc.npy"), "--device",
            "cpu"], tmp / "desc.npy"


def from_images(tmp: Path, args: argparse.Namespace) -> tuple[list[str], list[Path]]:
    out = tmp / "ds-img"
    return ["dataset", "from-images", str(tmp / "img-ref"), str(tmp / "img-qry"), "--method", "pixels", "--out",
            str(out), "--positives", str(tmp / "img-positives.csv"), "--radius", "2", "--device", "cpu"], \
        [out / s / "descriptors.npy" for s in ("reference", "query")]


COMMANDS = {"eval-single": eval_dataset("single"), "eval-seqmatch": eval_dataset("raw+seqmatch"),
            "eval-smoothing": eval_dataset("smoothing"), "index-build": index_build, "eval-index": eval_index,
            "localize-map": localize_map, "train": train, "describe": describe, "from-images": from_images}
IMAGE_COMMANDS = ("describe", "from-images")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.make_dataset:
        make_dataset(args, Path(args.make_dataset))
        if any(c in IMAGE_COMMANDS for c in args.commands.split(",")):
            make_images(args, Path(args.make_dataset))
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="seqnet-rss-"))
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    seqnet = [sys.executable, "-c", "import sys; from seqnet.cli import main; sys.exit(main())", "--threads",
              str(args.threads)]
    rows = []
    try:
        subprocess.run([sys.executable, __file__, *(argv if argv is not None else sys.argv[1:]), "--make-dataset",
                        str(tmp)], check=True)  # in a child: this process stays small for the children it forks
        for name in args.commands.split(","):
            cmd, counted = COMMANDS[name](tmp, args)
            load = os.getloadavg()[0]
            rc, secs, rss, log = run_measured([*seqnet, *cmd], env)
            nbytes = tree_bytes(counted)
            rows.append({"command": name, "argv": " ".join(["seqnet", *cmd]), "rc": rc, "seconds": round(secs, 1),
                         "peak_rss_bytes": rss, "map_bytes": nbytes, "budget_bytes": nbytes + BUDGET,
                         "within": rc == 0 and rss <= nbytes + BUDGET, "load_before": round(load, 2),
                         "load_after": round(os.getloadavg()[0], 2), "tail": log[-1500:]})
            print(f"{name}: rc {rc}, {secs:.1f} s, peak {rss / 2**20:.0f} MiB, map {nbytes / 2**20:.0f} MiB, "
                  f"over map {(rss - nbytes) / 2**20:+.0f} MiB, load {load:.2f}", flush=True)
            if rc:
                print(log[-2000:])
        res = {"n_db": args.n_db, "dim": args.dim, "dtype": args.dtype, "queries": args.queries,
               "images": args.images, "query_images": args.query_images, "threads": args.threads, "rows": rows}
        (out / "results.json").write_text(json.dumps(res, indent=2))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
