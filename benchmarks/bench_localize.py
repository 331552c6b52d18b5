"""Per-frame latency of the online Localizer on a synthetic map (default 14 000 frames × D = 4096).

Usage::

    python benchmarks/bench_localize.py [--frames 14000] [--dim 4096] [--out-dims 4096] [--w 5]
        [--methods hvpr,s1+seqmatch,raw+seqmatch] [--steps 300] [--threads 2] [--json FILE]

The map is random unit vectors; the query stream is map frames plus noise, driven along the route,
so every step does the real work (one S_1 frame descriptor, one S_L window descriptor, GEMVs against
the map, top-k, re-ranking). The models are untrained SeqNets of the given sizes (S_L: L = 5, kernel
``w``; S_1: D → ``out-dims``): latency does not depend on the weights. The first ``--warmup`` steps
are not timed. Prints mean / median / p95 per method and the load average before and after, and
with ``--breakdown`` the time of each part of an HVPR step (S_1, S_L, shortlist GEMV, re-rank).

Every step is memory-bound: it reads the models' weights and the map once. So each method (and each
part) is printed beside its *floor*: the bytes it must read divided by the memory bandwidth measured
in the same run on the same threads (a STREAM-style copy, ``2·bytes / time``, and a read-only sum).
``--precision float32,bfloat16,float16`` times the localiser's half-precision modes (half the bytes).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import subprocess
import sys
import time

import numpy as np
import torch

from seqnet.core import gemv
from seqnet.data.traverse import Dataset, Traverse
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.replay import dataset_localizer
from seqnet.sequence.model import SeqNet


def synthetic_map(n: int, dim: int, seed: int = 0) -> np.ndarray:
    """``[n, dim]`` float32 unit vectors, neighbours correlated (a route)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, dim), dtype=np.float32)
    x[1:] += 0.5 * x[:-1]
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def floors(nbytes: int, ms: float, bw: dict[str, float]) -> dict[str, float]:
    """The bytes, the floor (bytes ÷ copy and ÷ read bandwidth, ms) and measured ÷ floor."""
    copy_ms, read_ms = nbytes / bw["copy_gbs"] / 1e6, nbytes / bw["read_gbs"] / 1e6
    return {"mbytes": round(nbytes / 1e6, 1), "floor_copy_ms": round(copy_ms, 2), "floor_read_ms": round(read_ms, 2),
            "over_copy_floor": round(ms / copy_ms, 2) if nbytes else None,
            "over_read_floor": round(ms / read_ms, 2) if nbytes else None}


def stats(ms: np.ndarray) -> dict[str, float]:
    return {"mean": round(float(ms.mean()), 2), "median": round(float(np.median(ms)), 2),
            "p95": round(float(np.percentile(ms, 95)), 2), "max": round(float(ms.max()), 2)}


def localizer(ds: Dataset, models: dict, method: str, precision: str = "float32"):
    """The localiser of ``method`` over the map ``ds.reference`` (L = 5, CPU; fresh copies of the models, which a
    half-precision localiser casts)."""
    models = {r: copy.deepcopy(m) for r, m in models.items()}
    return dataset_localizer(ds, models, LocalizeConfig(method=method, seq_len=5, device="cpu", precision=precision))


def bandwidth(mib: int = 256, repeats: int = 7) -> dict[str, float]:
    """GB/s of a STREAM-style copy (``b = a``, counted as ``2·bytes / time``) and of a read-only sum over
    ``mib`` MiB arrays (far larger than the caches), best of ``repeats``, on torch's current threads."""
    a = torch.ones(mib * 2**18)
    b = torch.empty_like(a)
    copy_s = min(timed(lambda: b.copy_(a)) for _ in range(repeats))
    read_s = min(timed(lambda: a.sum()) for _ in range(repeats))
    return {"copy_gbs": round(2 * a.nbytes / copy_s / 1e9, 2), "read_gbs": round(a.nbytes / read_s / 1e9, 2)}


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def step_bytes(method: str, n: int, dim: int, out_dims: int, w: int, itemsize: int) -> dict[str, int]:
    """The bytes one localiser step of ``method`` must read: weights and the map (the query's few kB aside)."""
    s1, sl = dim * out_dims * itemsize, w * dim * out_dims * itemsize
    parts = {"hvpr": {"S_1 frame descriptor": s1, "S_L window descriptor": sl,
                      "shortlist search (exact index)": n * out_dims * itemsize},
             "s1+seqmatch": {"S_1 frame descriptor": s1, "distance row": n * out_dims * itemsize},
             "raw+seqmatch": {"distance row": n * dim * itemsize}}
    return parts.get(method, {})


def time_method(ds: Dataset, models: dict, method: str, queries: np.ndarray, warmup: int,
                precision: str = "float32") -> dict[str, float]:
    """Wall-clock latency per step (``Estimate.latency_ms``) and, separately, the CPU time of the
    calling thread per step (with one torch thread all the work is on it: what the step costs on a
    core of its own, whatever else the machine runs)."""
    t0 = time.perf_counter()
    loc = localizer(ds, models, method, precision)
    setup = time.perf_counter() - t0
    lat, cpu = [], []
    for q in queries:
        c0 = time.thread_time()
        lat.append(loc.step(q).latency_ms)
        cpu.append((time.thread_time() - c0) * 1e3)
    return {**stats(np.array(lat[warmup:])), "p99": round(float(np.percentile(lat[warmup:], 99)), 2),
            "cpu_median": round(float(np.median(cpu[warmup:])), 2),
            "setup_s": round(setup, 1)}


def breakdown(ds: Dataset, models: dict, queries: np.ndarray, steps: int, precision: str) -> dict[str, float]:
    """Median ms of each part of an HVPR step, timed apart."""
    loc = localizer(ds, models, "hvpr", precision)
    for q in queries[:10]:
        loc.step(q)
    s1, sl = loc.models["s1"], loc.models["seqnet"]
    q_sl = sl(torch.from_numpy(queries[:5])[None])
    win = torch.from_numpy(queries[:5])[None]
    parts = {"S_1 frame descriptor": lambda: s1(win[:, :1]),
             "S_L window descriptor": lambda: sl(win),
             "shortlist search (exact index)": lambda: loc.ref.search("seqnet", q_sl, 20),
             "HVPR step (all)": lambda: loc.step(queries[0])}
    out = {}
    with torch.no_grad():
        for name, fn in parts.items():
            ts = []
            for _ in range(steps):
                t0 = time.perf_counter()
                fn()
                ts.append((time.perf_counter() - t0) * 1e3)
            out[name] = round(float(np.median(ts)), 2)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=14000)
    p.add_argument("--dim", type=int, default=4096)
    p.add_argument("--out-dims", type=int, default=4096)
    p.add_argument("--w", type=int, default=5)
    p.add_argument("--methods", default="hvpr,s1+seqmatch,raw+seqmatch")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--breakdown", action="store_true")
    p.add_argument("--precision", default="float32", help="comma-separated: float32, bfloat16, float16")
    p.add_argument("--busy", type=int, default=0, help="processes spinning a core each while timing (a busy robot)")
    p.add_argument("--json")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=args.threads, user_api="blas")  # NumPy's OpenBLAS (seqnet.core.gemv) too, as the CLI
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        run(args)
    finally:
        for proc in spinners:
            proc.kill()


def run(args: argparse.Namespace) -> None:
    ref = synthetic_map(args.frames, args.dim)
    torch.manual_seed(0)
    models = {"seqnet": SeqNet(args.dim, args.out_dims, 5, args.w).eval(),
              "s1": SeqNet(args.dim, args.out_dims, 1, 1).eval()}
    t = Traverse(ref, np.arange(args.frames, dtype=np.float64))
    ds = Dataset(t, t, 1.0)
    rng = np.random.default_rng(1)
    start = int(rng.integers(0, args.frames - args.steps - args.warmup))
    queries = ref[start : start + args.steps + args.warmup] + 0.02 * rng.standard_normal(
        (args.steps + args.warmup, args.dim), dtype=np.float32)
    res = {"map": [args.frames, args.dim], "out_dims": args.out_dims, "w": args.w, "threads": args.threads,
           "gemv_forced": os.environ.get("SEQNET_GEMV"),
           "busy": args.busy,
           "load_before": os.getloadavg(), "bandwidth": bandwidth(), "methods": {}}
    print("bandwidth", res["bandwidth"], flush=True)
    for precision in args.precision.split(","):
        itemsize = 4 if precision == "float32" else 2
        for m in args.methods.split(","):
            r = time_method(ds, models, m, queries, args.warmup, precision)
            res["methods"][f"{m} {precision}"] = {**r, **floors(sum(step_bytes(
                m, args.frames, args.dim, args.out_dims, args.w, itemsize).values()), r["median"], res["bandwidth"])}
            print(m, precision, res["methods"][f"{m} {precision}"], flush=True)
        if args.breakdown:
            parts = step_bytes("hvpr", args.frames, args.dim, args.out_dims, args.w, itemsize)
            ms = breakdown(ds, models, queries, 50, precision)
            res[f"breakdown {precision}"] = {k: {"ms": v, **floors(parts.get(k, sum(parts.values())), v,
                                                                   res["bandwidth"])} for k, v in ms.items()}
            print(precision, res[f"breakdown {precision}"], flush=True)
    res["load_after"] = os.getloadavg()
    res["gemv"] = gemv.chosen()
    print("gemv kernels (tuned)", res["gemv"])
    print("load average before", res["load_before"], "after", res["load_after"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
