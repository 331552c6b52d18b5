"""HVPR with an approximate shortlist on a large map with real structure: Nordland64 among synthetic distractors.

The map holds the real summer frames of the Nordland64 test range (places 1940:2761, described by
the pixels descriptor and the S_L / S_1 models of ``seqnet benchmark nordland64``) embedded in a
route of synthetic distractor frames up to N_db frames in all. Distractors are drawn in the raw
descriptor space from the real descriptors' statistics (mean, top-256 principal axes with their
variances, isotropic residual, lag-1 correlation along the route, L2 norm) and described by the
same models, so a distractor has consistent S_L and S_1 descriptors. Queries are the real winter
frames of the test range. Distractor positions are far from every real one (never correct).

Compared per query (one at a time) and for R@1 over all test queries: HVPR with each approximate
shortlist and exact HVPR (exhaustive S_L search), each at every shortlist size K re-ranked by
SeqMatch (``--top-k 20,100,200``; one row per index setting and K, with its speed-up over this
run's whole-map SeqMatch), exact whole-map SeqMatch on S_1 (paper-style per query, and ours online:
one distance row per frame); and R@1 with the map rounded to float16.

Usage::

    seqnet benchmark nordland64 --data ../shared/data/nordland64 --out OUT/n64   # models and descriptors
    python benchmarks/bench_map_distractors.py --n64 OUT/n64 --sizes 100000,1000000 --out OUT/distractors
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import faiss
import numpy as np
import torch

from seqnet.data.io import load_dataset
from seqnet.data.traverse import Traverse
from seqnet.maps import MapArrays, MapConfig, load_map, write_map
from seqnet.matching.hvpr import order
from seqnet.matching.online import OnlineSeqMatch
from seqnet.matching.seqmatch import seqmatch_topk
from seqnet.metrics.recall import GroundTruth, recall
from seqnet.search.ann import AnnConfig, build_index, set_search_params
from seqnet.sequence.checkpoints import load_model
from seqnet.sequence.described import Described

FAR = 1e7  # distractor positions start here: never within the radius of a real place


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n64", required=True, help="output folder of seqnet benchmark nordland64 (dataset/, models/)")
    p.add_argument("--sizes", default="100000,1000000", help="N_db values (reference frames in all)")
    p.add_argument("--indexes", default="hnsw,ivf-flat", help="approximate shortlisters")
    p.add_argument("--nlist", type=int, default=1024, help="IVF lists (default 1024)")
    p.add_argument("--nprobe", default="32,128", help="IVF lists visited (each is measured)")
    p.add_argument("--ef-search", default="128,512", help="HNSW search breadths (each is measured)")
    p.add_argument("--hnsw-m", type=int, default=32, help="HNSW neighbours per node (default 32)")
    p.add_argument("--ef-construction", type=int, default=80, help="HNSW build breadth (default 80)")
    p.add_argument("--timed", type=int, default=100, help="queries timed one at a time (default 100)")
    p.add_argument("--top-k", default="20", help="shortlist sizes K re-ranked by SeqMatch (each is measured, "
                                                 "exact and with every index; default 20)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch threads while timing (default 1: on a shared machine a 2-thread parallel region "
                        "waits for a free core, which times the scheduler, not the method)")
    p.add_argument("--build-threads", type=int, default=2, help="threads while describing and building indexes")
    p.add_argument("--map", help="reuse this map (written by an earlier run with the same --n64) instead of "
                                 "describing the distractors again; one size only")
    p.add_argument("--keep-map", action="store_true", help="keep each map in --out/map-N (for a later --map) "
                   "instead of a temporary folder deleted afterwards")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="folder for results.json")
    return p.parse_args(argv)


def raw_model(train: np.ndarray) -> dict:
    """Statistics of the real raw descriptors: mean, top-256 principal axes and their spread, lag-1
    correlation along the route, residual spread."""
    mean = train.mean(0)
    u, s, vt = np.linalg.svd(train - mean, full_matrices=False)
    k = min(256, len(s))
    coords = u[:, :k] * s[:k]
    rho = float(np.clip(np.mean(np.sum(coords[1:] * coords[:-1], 0) / np.sum(coords * coords, 0)), 0.0, 0.99))
    resid = float(np.sqrt(max(np.sum(s[k:] ** 2) / len(train) / train.shape[1], 1e-12)))
    return {"mean": mean.astype(np.float32), "axes": vt[:k].astype(np.float32), "std": coords.std(0), "rho": rho,
            "resid": resid}


def distractor_raw(model: dict, n: int, rng: np.random.Generator, chunk: int = 32768):
    """Yield ``[<=chunk, D]`` raw distractor frames: an AR(1) walk along the principal axes of the real ones."""
    from scipy.signal import lfilter

    rho, std, dim = model["rho"], model["std"], model["axes"].shape[1]
    state = rho * rng.standard_normal((1, len(std))) * std
    for a in range(0, n, chunk):
        m = min(chunk, n - a)
        eps = rng.standard_normal((m, len(std))) * std * np.sqrt(1 - rho**2)
        ys, state = lfilter([1.0], [1.0, -rho], eps, axis=0, zi=state)
        x = model["mean"] + ys.astype(np.float32) @ model["axes"]
        x += model["resid"] * rng.standard_normal((m, dim), dtype=np.float32)
        yield x / np.linalg.norm(x, axis=1, keepdims=True)


def segments(ref: Traverse, model: dict, n_db: int, seed: int):
    """Yield ``(raw descriptors, positions)`` of the map's sequences: distractor chunks, the real reference
    in the middle, distractor chunks (each chunk its own sequence: memory stays bounded)."""
    rng = np.random.default_rng(seed)
    n_dis = max(0, n_db - len(ref))
    offset = 0
    for part in (n_dis // 2, None, n_dis - n_dis // 2):
        if part is None:
            yield np.asarray(ref.descriptors, np.float32), ref.positions
            continue
        for raw in distractor_raw(model, part, rng):
            yield raw, FAR + offset + np.arange(len(raw), dtype=np.float64)[:, None]
            offset += len(raw)


def build_arrays(ref: Traverse, model: dict, n_db: int, conf: MapConfig, models: dict, seed: int):
    """The map's arrays (see :func:`segments`), described by the models sequence by sequence."""
    sl, fr, items, starts, pos, bounds, offset = [], [], [], [], [], [], 0
    for raw, positions in segments(ref, model, n_db, seed):
        t = Traverse(raw, positions, provenance=ref.provenance)
        d = Described(t.descriptors, t.seq_bounds, conf.windows, models, torch.device("cpu"), "reference")
        sl.append(d.items(conf.shortlist).numpy())
        fr.append(d.frames(conf.frames_descriptor).numpy())
        items.append(d.side.items + offset)
        starts.append(d.side.match_starts + offset)
        pos.append(t.positions)
        bounds.append(np.tile([[offset, offset + len(raw)]], (len(raw), 1)))
        offset += len(raw)
    return MapArrays(np.concatenate(sl), np.concatenate(fr), np.concatenate(items), np.concatenate(starts),
                     np.concatenate(pos), seq_bounds=np.concatenate(bounds))


def timed(fn, n: int) -> tuple[float, float]:
    for i in range(3):
        fn(i % n)
    ts = []
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        ts.append((time.perf_counter() - t0) * 1e3)
    return statistics.fmean(ts), statistics.pstdev(ts)


def r1(ranked: np.ndarray, truth: GroundTruth) -> float:
    return round(float(recall(ranked, truth, (1,))["recall@1"]), 4)


def overlap(approx: np.ndarray, exact: np.ndarray) -> float:
    """Mean fraction of the exact top-K that the approximate top-K keeps."""
    return round(float(np.mean([len(np.intersect1d(a, e)) / e.shape[0] for a, e in zip(approx, exact, strict=True)])),
                 4)


def hvpr_rows(mp, q: tuple, truth, ks: list[int], pick: np.ndarray, name: str, params: dict,
              exact_top: np.ndarray) -> list[dict]:
    """One row per K: HVPR's R@1 over all queries, shortlist recall and ms per query (one at a time) with
    the map's current index (``name == "exact"``: the exhaustive S_L search)."""
    sq, qf, qs = q
    exact, rows = name == "exact", []
    for k in ks:
        cand = exact_top[:, :k] if exact else mp.search(mp.config.shortlist, sq, k)[1]
        row = {"index": name, **params, "top_k": k,
               "recall@1": r1(order(mp.pair_scores(qf, qs, cand), cand, mp.config.match_len)[1], truth)}
        if not exact:
            row["shortlist_recall"] = overlap(cand, exact_top[:, :k])
        row["ms"] = timed(lambda i, k=k: mp.localize(sq[pick[i] : pick[i] + 1], qf, qs[pick[i] : pick[i] + 1], k,
                                                     exact=exact), len(pick))
        rows.append(row)
    return rows


def whole_map(mp, qf, qs, truth, k: int, pick: np.ndarray) -> dict:
    """Exact whole-map SeqMatch on S_1: R@1, batch ms per query, paper-style and ours online (ms per query)."""
    lm = mp.config.match_len
    t0 = time.perf_counter()
    whole = seqmatch_topk(qf, mp.frames, lm, 1, qs, mp.match_starts)[1]
    res = {"recall@1": r1(whole, truth), "batch_ms_per_query": (time.perf_counter() - t0) * 1e3 / len(qs)}
    res["paper_ms"] = timed(lambda i: seqmatch_topk(
        qf[qs[pick[i]] : qs[pick[i]] + lm], mp.frames, lm, k, np.zeros(1, np.int64), mp.match_starts), len(pick))
    online = OnlineSeqMatch(torch.from_numpy(np.asarray(mp.frames, np.float32)), lm)
    for t in range(lm - 1):
        online.step(qf[t])
    sel, frame = torch.as_tensor(mp.match_starts), iter(range(lm - 1, len(qf)))
    res["online_ms"] = timed(lambda i: online.topk(online.step(qf[next(frame)]), k, sel),
                             min(len(pick), len(qf) - lm - 3))
    return res


def float16_recall(mp, sq, qf, qs, truth, k: int) -> dict:
    """R@1 of exact HVPR (top ``k``) and whole-map SeqMatch with the map rounded to float16 (changes ``mp``)."""
    lm = mp.config.match_len
    for name, arr in (("shortlist", mp.shortlist), ("frames", mp.frames)):
        setattr(mp, name, np.asarray(arr).astype(np.float16))
    cand = mp.search(mp.config.shortlist, sq, k, exact=True)[1]
    return {"hvpr_exact": r1(order(mp.pair_scores(qf, qs, cand), cand, lm)[1], truth),
            "seqmatch_all": r1(seqmatch_topk(qf, mp.frames, lm, 1, qs, mp.match_starts)[1], truth)}


def measure(mp, qd, truth, args, indexes: dict) -> dict:
    ks = sorted(int(k) for k in args.top_k.split(","))
    q = sq, qf, qs = (qd.items(mp.config.shortlist).numpy(), qd.frames(mp.config.frames_descriptor).numpy(),
                      qd.side.match_starts)
    pick = np.linspace(0, len(sq) - 1, min(args.timed, len(sq))).round().astype(int)
    exact_top = mp.search(mp.config.shortlist, sq, ks[-1], exact=True)[1]
    rows = hvpr_rows(mp, q, truth, ks, pick, "exact", {}, exact_top)
    for name, (index, ann, params) in indexes.items():
        set_search_params(index, ann)
        mp.index = index
        rows += hvpr_rows(mp, q, truth, ks, pick, name, params, exact_top)
    whole = whole_map(mp, qf, qs, truth, ks[0], pick)
    for row in rows:
        row["speedup_paper"] = round(whole["paper_ms"][0] / row["ms"][0], 1)
        row["speedup_online"] = round(whole["online_ms"][0] / row["ms"][0], 1)
    return {"hvpr": rows, "seqmatch_all": whole, "float16_recall@1": float16_recall(mp, sq, qf, qs, truth, ks[0])}


def run_size(n_db: int, args, ds, models, tmp: Path) -> dict:
    test = ds.split("test")
    a, b = ds.splits["train"]["reference"]
    train = np.concatenate([ds.reference.descriptors[a:b], ds.query.descriptors[a:b]])
    conf = MapConfig(seq_len=5, match_len=5, ann=AnnConfig(kind="flat"), split="test")
    t0 = time.perf_counter()
    if args.map:
        mp = load_map(args.map, "cpu")
    else:
        arrays = build_arrays(test.reference, raw_model(train), n_db, conf, models, args.seed)
        mp = load_map(write_map(tmp / f"map-{n_db}", conf, arrays, models, ds.reference.provenance,
                                {"input_dim": ds.reference.dim, "bench": "nordland64 among distractors"}), "cpu")
        del arrays
    describe_s = time.perf_counter() - t0
    qd = mp.describe(test.query)
    truth = GroundTruth(test.query.positions[qd.side.items], mp.positions[mp.items], ds.radius)
    indexes, build_s = {}, {}
    for kind in filter(None, args.indexes.split(",")):
        t1 = time.perf_counter()
        ann = AnnConfig(kind=kind, nlist=args.nlist, hnsw_m=args.hnsw_m, ef_construction=args.ef_construction)
        index = build_index(np.asarray(mp.shortlist), ann)
        build_s[kind] = round(time.perf_counter() - t1, 1)
        key, values = ("ef_search", args.ef_search) if kind == "hnsw" else ("nprobe", args.nprobe)
        for v in values.split(","):
            indexes[f"{kind}@{key}={v}"] = (index, ann.replace(**{key: int(v)}), {key: int(v)})
    torch.set_num_threads(args.threads)
    faiss.omp_set_num_threads(args.threads)
    res = measure(mp, qd, truth, args, indexes)
    torch.set_num_threads(args.build_threads)
    faiss.omp_set_num_threads(args.build_threads)
    return {"n_db": len(mp.frames), "items": len(mp.items), "queries": len(qd.side.items), "map_bytes": mp.nbytes,
            "describe_s": round(describe_s, 1), "index_build_s": build_s, "loadavg": os.getloadavg(),
            "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, **res}


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    torch.set_num_threads(args.build_threads)
    n64 = Path(args.n64)
    ds = load_dataset(n64 / "dataset", mmap=False)
    ds.splits = {"train": {"reference": (0, 1650), "query": (0, 1650)},
                 "test": {"reference": (1940, 2761), "query": (1940, 2761)}}
    models = {r: load_model(n64 / "models" / f"{r}.pt") for r in ("seqnet", "s1")}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    tmp = Path(tempfile.mkdtemp(prefix="seqnet-distractors-"))
    try:
        for n_db in (int(x) for x in args.sizes.split(",")):
            results.append(run_size(n_db, args, ds, models, out if args.keep_map else tmp))
            shutil.rmtree(tmp / f"map-{n_db}", ignore_errors=True)
            (out / "results.json").write_text(json.dumps({"args": vars(args), "results": results}, indent=2))
            print(json.dumps(results[-1], indent=1))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
