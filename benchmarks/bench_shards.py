"""A sharded IVF index against one index built in one process, on a synthetic map of millions of places.

Writes ``N × D`` float32 descriptors (a Gaussian mixture: places around 4096 centres) to a ``.npy``,
trains one IVF coarse quantizer on a sample (:func:`seqnet.maps.shards.train_ivf`), then in separate
child processes (each reports its own peak RSS, ``resource.getrusage``):

* ``one``: the trained index + all N rows added in one process (the usual ``seqnet index build``);
* ``sharded``: the rows in S contiguous shards, each shard's inverted lists built in its own thread,
  merged with FAISS's ``merge_ondisk`` into ``index.ivfdata`` (:func:`build_sharded_index`);
* ``open``: the merged index opened memory-mapped in a fresh process (:func:`open_merged`).

Every child searches the same queries (noisy copies of places); the results must be identical
(distances and ids). Prints build times, file sizes, peak RSS and the load average; ``--json`` writes them.

Usage::

    python benchmarks/bench_shards.py --n 4000000 --dim 32 --shards 4 --out /tmp/shard/bench
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from seqnet.maps.shards import build_sharded_index, open_merged, sample_rows, split_rows, train_ivf, train_sample_size
from seqnet.search.ann import AnnConfig, load_index, save_index, search


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=4_000_000, help="places (rows)")
    p.add_argument("--dim", type=int, default=32)
    p.add_argument("--shards", type=int, default=4)
    p.add_argument("--nlist", type=int, default=1024)
    p.add_argument("--nprobe", type=int, default=16)
    p.add_argument("--queries", type=int, default=1000)
    p.add_argument("--k", type=int, default=10)
    p.add_argument("--out", type=Path, default=Path("/tmp/shard/bench"))
    p.add_argument("--json", type=Path, help="write the figures here")
    return p.parse_args(argv)


def make_data(path: Path, n: int, d: int, seed: int = 0) -> float:
    """``[n, d]`` float32 places around 4096 centres, written in blocks; seconds taken."""
    t0, rng = time.perf_counter(), np.random.default_rng(seed)
    centres = rng.standard_normal((4096, d)).astype(np.float32) * 4
    x = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(n, d))
    for a in range(0, n, 1 << 20):
        b = min(n, a + (1 << 20))
        x[a:b] = centres[rng.integers(0, len(centres), b - a)] + rng.standard_normal((b - a, d), dtype=np.float32)
    x.flush()
    del x
    return time.perf_counter() - t0


def peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(job: str, data: Path, trained: Path, work: Path, shards: int, queries: np.ndarray, k: int,
          conf: AnnConfig) -> dict:
    """One measured phase in a fresh process: ``one``, ``sharded`` or ``open``."""
    x = np.load(data, mmap_mode="r")
    t0 = time.perf_counter()
    if job == "one":
        index = load_index(trained)
        for a in range(0, len(x), 1 << 18):
            index.add(np.ascontiguousarray(x[a:a + (1 << 18)]))
    elif job == "sharded":
        build_sharded_index([x[a:b] for a, b in split_rows(len(x), shards)], conf, work / "index.faiss",
                            workers=shards, trained=load_index(trained))
        index = open_merged(work / "index.faiss", conf)
    else:
        index = open_merged(work / "index.faiss", conf)
    build = time.perf_counter() - t0
    index.nprobe = conf.nprobe
    t1 = time.perf_counter()
    dist, ids = search(index, queries, k)
    return {"job": job, "build_s": round(build, 2), "search_ms_per_query": round((time.perf_counter() - t1)
            / len(queries) * 1e3, 3), "peak_rss_mib": round(peak_mib(), 1), "dist": dist, "ids": ids}


def main(argv: list[str] | None = None) -> dict:
    a = parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    data, work = a.out / "places.npy", a.out / "merged"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    load0 = os.getloadavg()
    fig: dict = {"n": a.n, "dim": a.dim, "shards": a.shards, "nlist": a.nlist, "nprobe": a.nprobe,
                 "data_mib": round(a.n * a.dim * 4 / 2**20, 1), "data_s": round(make_data(data, a.n, a.dim), 1)}
    conf = AnnConfig(kind=f"IVF{a.nlist},Flat", nprobe=a.nprobe)
    x = np.load(data, mmap_mode="r")
    t0 = time.perf_counter()
    sample = sample_rows(x, train_sample_size(a.n, conf, a.dim))
    save_index(train_ivf(sample, a.n, conf), a.out / "trained.faiss")
    fig.update(train_rows=len(sample), train_s=round(time.perf_counter() - t0, 1))
    rng = np.random.default_rng(1)
    queries = np.asarray(x[rng.integers(0, a.n, a.queries)]) + 0.05 * rng.standard_normal((a.queries, a.dim))
    del x, sample
    ctx = mp.get_context("spawn")
    runs = {}
    for job in ("one", "sharded", "open"):
        with ctx.Pool(1) as pool:
            runs[job] = pool.apply(child, (job, data, a.out / "trained.faiss", work, a.shards, queries, a.k, conf))
    for job in ("sharded", "open"):
        same = np.array_equal(runs[job]["ids"], runs["one"]["ids"]) and np.array_equal(runs[job]["dist"],
                                                                                       runs["one"]["dist"])
        fig[f"{job}_identical_to_one"] = bool(same)
    for job, r in runs.items():
        fig[job] = {key: v for key, v in r.items() if key not in ("dist", "ids", "job")}
    fig.update(index_faiss_mib=round(os.path.getsize(work / "index.faiss") / 2**20, 2),
               index_ivfdata_mib=round(os.path.getsize(work / "index.ivfdata") / 2**20, 1),
               load_average_start=[round(v, 2) for v in load0], load_average_end=[round(v, 2) for v in os.getloadavg()],
               cpus=os.cpu_count())
    print(json.dumps(fig, indent=2))
    if a.json:
        a.json.write_text(json.dumps(fig, indent=2) + "\n")
    return fig


if __name__ == "__main__":
    main()
