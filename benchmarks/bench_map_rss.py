"""Peak memory of ``seqnet eval --index`` on a large map: is it bounded by the map's bytes + 512 MB?

Writes a synthetic dataset (a smooth route of N_db reference frames of D dimensions, and a query
traverse that revisits a stretch of it with noise) to a temporary folder, builds a map of it with
``seqnet index build`` (exact ``flat`` shortlist over memory-mapped descriptors), then runs
``seqnet eval --index`` in a child process and reads the child's peak resident set size
(``ru_maxrss`` from ``os.wait4``). The map's files count in full (their pages are resident once
read); the reference descriptors of the dataset are never read by the evaluation.

Usage::

    python benchmarks/bench_map_rss.py --n-db 100000 --dim 4096 --out OUT/rss
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from seqnet.core.provenance import make as make_provenance
from seqnet.data.io import save_dataset
from seqnet.data.traverse import Dataset, Traverse
from seqnet.pipelines.timing.synth import route

BUDGET = 512 * 2**20


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-db", type=int, default=100000)
    p.add_argument("--dim", type=int, default=4096)
    p.add_argument("--queries", type=int, default=2000, help="query frames (a stretch of the route revisited)")
    p.add_argument("--noise", type=float, default=1.0)
    p.add_argument("--dtype", default="float32", choices=("float32", "float16"))
    p.add_argument("--methods", default="", help="eval --method (default: the map's HVPR and its shortlister)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", required=True)
    return p.parse_args(argv)


def make_dataset(args: argparse.Namespace, root: Path) -> Path:
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
        proc.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        out = log.read().decode(errors="replace")
    return proc.returncode, time.perf_counter() - t0, usage.ru_maxrss * 1024, out


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="seqnet-rss-"))
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    seqnet = [sys.executable, "-c", "import sys; from seqnet.cli import main; sys.exit(main())", "--threads",
              str(args.threads)]
    try:
        t0 = time.perf_counter()
        ds = make_dataset(args, tmp)
        made_s = time.perf_counter() - t0
        build = [*seqnet, "index", "build", "--dataset", str(ds), "--split", "all", "--shortlist", "smoothing",
                 "--rerank", "raw+seqmatch", "--index", "flat", "--dtype", args.dtype, "--out", str(tmp / "map")]
        rc_b, build_s, build_rss, log_b = run_measured(build, env)
        if rc_b:
            raise SystemExit(f"index build failed: {log_b[-2000:]}")
        map_bytes = sum(p.stat().st_size for p in (tmp / "map").rglob("*") if p.is_file())
        ev = [*seqnet, "eval", "--dataset", str(ds), "--split", "all", "--index", str(tmp / "map"), "--json",
              str(out / "eval.json")] + (["--method", args.methods] if args.methods else [])
        load_before = os.getloadavg()
        rc_e, eval_s, eval_rss, log_e = run_measured(ev, env)
        res = {"n_db": args.n_db, "dim": args.dim, "dtype": args.dtype, "queries": args.queries,
               "dataset_seconds": round(made_s, 1), "build_seconds": round(build_s, 1),
               "build_peak_rss_bytes": build_rss, "map_bytes": map_bytes, "eval_rc": rc_e,
               "eval_seconds": round(eval_s, 1), "eval_peak_rss_bytes": eval_rss,
               "eval_rss_minus_map_mib": round((eval_rss - map_bytes) / 2**20, 1),
               "within_map_plus_512mb": eval_rss <= map_bytes + BUDGET,
               "loadavg": [load_before, os.getloadavg()], "eval_output": log_e[-3000:]}
        (out / "results.json").write_text(json.dumps(res, indent=2))
        print(json.dumps({k: v for k, v in res.items() if k != "eval_output"}, indent=1))
        print(log_e[-1500:])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
