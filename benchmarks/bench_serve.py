"""Load test of ``seqnet serve`` on localhost (docs/serve.md): many sessions at camera pace on a 14k-frame map.

Usage::

    python benchmarks/bench_serve.py [--frames 14000] [--dim 1024] [--index hnsw] [--sessions 16] [--fps 10]
        [--per-session 100] [--saturate-s 8] [--workers 2] [--json FILE]

Builds a synthetic route map (``--frames`` unit vectors of ``--dim``, an ``--index`` over Delta-free smoothing
shortlist descriptors, raw+seqmatch re-ranking, causal windows; method ``hvpr-smoothing:raw+seqmatch``), starts
``seqnet serve`` on it as a subprocess (``--no-auth``, a free port), and measures:

1. alone: each of the ``--sessions`` streams (``--per-session`` noisy frames of a stretch of the route) in a session
   of its own, one after the other, frames back to back: the single-client answers and round-trip latency;
2. load: all streams at once, each at ``--fps`` (frames sent on a fixed schedule, each camera's at a random phase;
   ``--aligned``: all at the same instants): errors, answers identical to 1.,
   p99 round-trip latency against ``3 × single-client median + 50 ms``;
3. RSS of the server after start-up and after the load, against ``1.5 × start-up + 200 MB``;
4. saturation: 1, 2, 4, ... ``--sessions`` sessions sending back to back for ``--saturate-s`` seconds each: the
   highest total frame rate served, beside ``seqnet localize --map`` on the same frames (its per-frame time, one
   thread, no HTTP).

The clients run in this process (threads, standard-library HTTP): on a 2-core machine they share the cores with the
server, so the rates are those of server and clients together. Everything is bounded: frame counts, and every
request and phase by a timeout. The machine's load average (1, 5, 15 min) before and after is written beside the
figures: on a shared machine the latencies follow it.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from seqnet.client import Client, ClientError

METHOD = "hvpr-smoothing:raw+seqmatch"
COMPARED = ("frame", "estimate", "estimate_name", "score", "confidence", "position", "full_window")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=14000, help="frames of the map")
    p.add_argument("--dim", type=int, default=1024)
    p.add_argument("--index", default="hnsw", help="the map's index (seqnet index build --index)")
    p.add_argument("--sessions", type=int, default=16)
    p.add_argument("--fps", type=float, default=10.0, help="frames per second of each session under load")
    p.add_argument("--per-session", type=int, default=100, help="frames each session sends")
    p.add_argument("--saturate-s", type=float, default=8.0, help="seconds of each saturation step")
    p.add_argument("--workers", type=int, default=2, help="seqnet serve --workers")
    p.add_argument("--aligned", action="store_true", help="every session sends at the same instants (worst case; "
                   "default: each camera at a random phase)")
    p.add_argument("--noise", type=float, default=0.5)
    p.add_argument("--keep", help="build the map here (and keep it) instead of a temporary folder")
    p.add_argument("--json", help="write the figures here")
    return p.parse_args(argv)


def build_map(args: argparse.Namespace, root: Path) -> tuple[Path, list[np.ndarray]]:
    """The map in ``root/map`` and ``--sessions`` query streams (noisy stretches of the route, each its own)."""
    from seqnet.cli import main as cli
    from seqnet.core.provenance import make as make_provenance
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.pipelines.timing.synth import route

    rng = np.random.default_rng(0)
    frames = route(args.frames, args.dim, rng)
    starts = np.linspace(0, args.frames - args.per_session - 1, args.sessions).astype(int)
    streams = []
    for s0 in starts:
        q = frames[s0 : s0 + args.per_session] * np.sqrt(args.dim)
        q = q + args.noise * rng.standard_normal(q.shape).astype(np.float32)
        streams.append((q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32))
    if not (root / "map").is_dir():
        prov = make_provenance("synthetic", {"generator": "bench_serve", "dim": args.dim}, dim=args.dim)
        pos = np.c_[np.arange(args.frames, dtype=np.float64), np.zeros(args.frames)]
        ref = Traverse(frames, pos, provenance=prov, name="reference")
        qry = Traverse(np.concatenate(streams), np.zeros((len(streams) * args.per_session, 2)), provenance=prov,
                       name="query")
        save_dataset(Dataset(ref, qry, radius=2.0, name=f"route-{args.frames}x{args.dim}"), root / "ds")
        code = cli(["-q", "index", "build", "--dataset", str(root / "ds"), "--split", "all", "--shortlist",
                    "smoothing", "--rerank", "raw+seqmatch", "--index", args.index, "--window", "causal", "--out",
                    str(root / "map")])
        assert code == 0, "seqnet index build failed"
    return root / "map", streams


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def start_server(map_dir: Path, workers: int) -> tuple[subprocess.Popen, str]:
    p = subprocess.Popen([sys.executable, "-m", "seqnet", "serve", "--map", str(map_dir), "--method", METHOD,
                          "--port", "0", "--no-auth", "--device", "cpu", "--workers", str(workers),
                          "--max-sessions", "256"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    if "serving" not in line:
        p.kill()
        raise SystemExit(f"seqnet serve did not start: {line!r} {p.stderr.read()[-2000:]}")
    return p, re.search(r"http://[^\s;]+/", line)[0]


def run_stream(url: str, frames: np.ndarray, fps: float | None, out: dict, key: int, deadline: float,
               phase: float = 0.0) -> None:
    """One session sending ``frames`` (at ``fps`` on a fixed schedule shifted by ``phase`` seconds, or back to
    back); answers and latencies."""
    answers, lat, errors = [], [], []
    try:
        with Client(url, timeout=30).session() as s:
            t0 = time.perf_counter()
            for i, f in enumerate(frames):
                if fps:
                    wait = t0 + phase + i / fps - time.perf_counter()
                    if wait > 0:
                        time.sleep(wait)
                if time.monotonic() > deadline:
                    errors.append("deadline")
                    break
                a = time.perf_counter()
                try:
                    answers.append(s.send(f))
                except ClientError as e:
                    errors.append(f"{e.status}: {e.message}")
                    continue
                lat.append((time.perf_counter() - a) * 1e3)
    except ClientError as e:
        errors.append(f"{e.status}: {e.message}")
    out[key] = {"answers": answers, "latency_ms": lat, "errors": errors}


def in_threads(url: str, streams: list[np.ndarray], fps: float | None, limit_s: float, aligned: bool = False) -> dict:
    """Every stream in a session of its own, at once; at ``fps``, each camera's clock at a random phase (seeded)
    unless ``aligned`` (every session sends at the same instants: the worst case)."""
    out: dict = {}
    deadline = time.monotonic() + limit_s
    rng = np.random.default_rng(1)
    phases = [0.0 if aligned or not fps else float(rng.uniform(0, 1 / fps)) for _ in streams]
    threads = [threading.Thread(target=run_stream, args=(url, s, fps, out, i, deadline, phases[i]))
               for i, s in enumerate(streams)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(limit_s + 30)
    return out


def saturate(url: str, streams: list[np.ndarray], seconds: float) -> list[dict]:
    """Total frames per second served with 1, 2, 4, ... sessions sending back to back for ``seconds`` each."""
    counts = sorted({2**k for k in range(8) if 2**k < len(streams)} | {len(streams)})
    rows = []
    for n in counts:
        done, failed, stop = [0] * n, [], threading.Event()

        def loop(i: int, done: list[int] = done, failed: list[str] = failed, stop: threading.Event = stop) -> None:
            try:
                with Client(url, timeout=30).session() as s:
                    while not stop.is_set():
                        s.send(streams[i][done[i] % len(streams[i])])
                        done[i] += 1
            except ClientError as e:
                failed.append(f"{e.status}: {e.message}")

        threads = [threading.Thread(target=loop, args=(i,)) for i in range(n)]
        for t in threads:
            t.start()
        time.sleep(1.0)  # ramp-up, not counted
        before, t0 = sum(done), time.perf_counter()
        time.sleep(seconds)
        rate = (sum(done) - before) / (time.perf_counter() - t0)
        stop.set()
        for t in threads:
            t.join(30)
        rows.append({"sessions": n, "frames_per_s": round(rate, 1), "errors": len(failed)})
        print(f"saturation: {n} sessions back to back: {rate:.1f} frames/s", flush=True)
    return rows


def localize_rate(map_dir: Path, frames: np.ndarray, root: Path) -> dict:
    """``seqnet localize --map`` on ``frames``: its per-frame time (median, mean) and the rate that gives."""
    np.save(root / "stream.npy", frames)
    p = subprocess.run([sys.executable, "-m", "seqnet", "-q", "localize", "--map", str(map_dir), "--query",
                        str(root / "stream.npy"), "--method", METHOD, "--device", "cpu", "--out",
                        str(root / "track.csv")], capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, p.stderr[-2000:]
    lat = json.loads((root / "track.json").read_text())["summary"]["latency_ms"]
    return {"median_ms": round(lat["median"], 3), "mean_ms": round(lat["mean"], 3),
            "frames_per_s": round(1000 / lat["mean"], 1)}


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep or tmp)
        root.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        map_dir, streams = build_map(args, root)
        print(f"map: {args.frames} frames x D={args.dim}, {args.index} ({time.perf_counter() - t0:.0f} s)", flush=True)
        server, url = start_server(map_dir, args.workers)
        try:
            figures = measure(args, server, url, streams, map_dir, root)
        finally:
            server.send_signal(signal.SIGTERM)
            try:
                server.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                server.kill()
        figures["server_exit"] = server.returncode
    print(json.dumps(figures, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return figures


def measure(args: argparse.Namespace, server: subprocess.Popen, url: str, streams: list[np.ndarray], map_dir: Path,
            root: Path) -> dict:
    rss_start, load_before = rss_mb(server.pid), os.getloadavg()
    alone = {i: in_threads(url, [s], None, 300)[0] for i, s in enumerate(streams)}  # one session at a time
    single = np.concatenate([alone[i]["latency_ms"][5:] for i in alone])
    limit = args.per_session / args.fps + 120
    load = in_threads(url, streams, args.fps, limit, args.aligned)
    rss_load = rss_mb(server.pid)
    errors = [e for r in load.values() for e in r["errors"]] + [e for r in alone.values() for e in r["errors"]]
    same = all([{k: a[k] for k in COMPARED} for a in load[i]["answers"]]
               == [{k: a[k] for k in COMPARED} for a in alone[i]["answers"]] for i in range(len(streams)))
    lat = np.concatenate([load[i]["latency_ms"] for i in load])
    median, p99 = float(np.median(single)), float(np.percentile(lat, 99))
    print(f"load: {len(lat)} frames, {len(errors)} errors, identical answers: {same}; p99 {p99:.1f} ms "
          f"(single-client median {median:.2f} ms)", flush=True)
    sat = saturate(url, streams, args.saturate_s)
    own = localize_rate(map_dir, np.concatenate(streams), root)
    return {"map": {"frames": args.frames, "dim": args.dim, "index": args.index, "method": METHOD},
            "sessions": args.sessions, "fps": args.fps, "aligned": args.aligned, "per_session": args.per_session,
            "workers": args.workers,
            "cpus": len(os.sched_getaffinity(0)), "errors": errors[:20], "n_errors": len(errors),
            "load_average": {"before": [round(v, 2) for v in load_before],
                             "after": [round(v, 2) for v in os.getloadavg()]},
            "identical_to_single_session": same,
            "single_client_ms": {"median": round(median, 2), "p99": round(float(np.percentile(single, 99)), 2)},
            "load_ms": {"median": round(float(np.median(lat)), 2), "p99": round(p99, 2),
                        "max": round(float(lat.max()), 2), "frames": int(len(lat))},
            "p99_bound_ms": round(3 * median + 50, 2), "p99_ok": p99 <= 3 * median + 50,
            "rss_mb": {"start": round(rss_start, 1), "after_load": round(rss_load, 1),
                       "bound": round(1.5 * rss_start + 200, 1)}, "rss_ok": rss_load <= 1.5 * rss_start + 200,
            "saturation": sat, "max_frames_per_s": max(r["frames_per_s"] for r in sat),
            "seqnet_localize": own}


if __name__ == "__main__":
    main()
