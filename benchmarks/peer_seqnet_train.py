"""One training epoch of the original seqNet ``main.py`` against ``seqnet train``, same data and settings.

The original code (github.com/oravus/seqNet) is fetched separately and run as it is, never copied
here: its ``main.py`` reads ``./structFiles/<set>.db`` and ``./data/descData/netvlad-pytorch/
nordland-clean-{summer,winter}.npy`` relative to the working directory (``get_datasets.py``), so this
script prepares exactly that layout in a work folder and runs the original from there:

- ``structFiles/`` → the original repository's own struct files (the Nordland train struct
  ``nordland_train_d-40_d2-10.db``: 15000 reference and 15000 query frames, negatives beyond 40
  frames, positives within 10; val ``nordland_val_d-1_d2-1.db``);
- the two descriptor arrays, ``[21200, D]`` float32 (the original indexes frames 0..21199 of the clean
  list: train 0..14999, val 18200..21199), D = 4096 as in the paper (NetVLAD + PCA): a synthetic
  route (each frame a small random step from the last; winter = summer plus noise, so that about
  as many negatives violate the margin as on real descriptors);
- the same arrays and struct files converted by ``seqnet dataset from-seqnet --preset nordland``.

Commands (``--variant s5``: S_5, w 5; ``s1``: S_1, w 1; both ``--outDims 4096``)::

    python main.py --mode train --pooling seqnet --dataset nordland-sw --seqL 5 --w 5 --outDims 4096
        --expName w5 --nocuda --nEpochs 1 --evalEvery 2 --threads T
    seqnet --threads T train --dataset DS --out RUN --seq-len 5 --w 5 --out-dims 4096 --epochs 1
        --val-split none --cache-refresh 0 --margin 0.316228 --seed 123 -v

``--nEpochs 1`` bounds the original to one epoch and ``--evalEvery 2`` skips its validation (epoch
1 is not a multiple of 2), so neither side validates. The other settings are both sides' defaults,
which agree: SGD lr 1e-4, momentum 0.9, weight decay 1e-3, batch 16, 10 hard negatives among 1000
sampled; the original's margin 0.1 is on squared distances (its loss uses ``margin ** 0.5``), hence
seqnet's 0.316228; the original's mining cache is computed once per epoch (``--cacheRefreshRate 0``),
hence ``--cache-refresh 0``. ``--threads T`` is the original's data-loader workers; both sides run
with ``OMP_NUM_THREADS = MKL_NUM_THREADS = T`` torch threads.

The epoch time is the span between two lines each side prints, timestamped as they arrive: the
original's ``===> Training model`` .. ``===> Epoch 1 Complete`` (mining cache, mining, steps);
seqnet's ``training S_...`` .. ``epoch 1/1: ...`` (the same, plus writing its checkpoints, which the
original with no validation skips). Runs alternate A B A B; the best of each is kept.

Usage::

    python benchmarks/peer_seqnet_train.py --orig /path/to/seqNet --variant s5 --threads 2
    python benchmarks/peer_seqnet_train.py --orig /path/to/seqNet --variant s1 --dim 1024 --json out.json

The original needs ``tensorboardX``, ``h5py``, ``faiss-cpu``, ``scikit-learn``, ``scipy`` and
``tqdm`` in the same Python (``pip install tensorboardX``; the others are seqnet's own or its
extras'); they are not seqnet's dependencies.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
N_FRAMES = 21200  # the original indexes the clean list up to the end of its val split (18200..21199)
STRUCTS = ("nordland_train_d-40_d2-10.db", "nordland_val_d-1_d2-1.db", "nordland_test_d-1_d2-1.db")
VARIANTS = {"s5": {"seqL": 5, "w": 5, "name": "S_5"}, "s1": {"seqL": 1, "w": 1, "name": "S_1"}}
MARGIN = 0.1  # the original's default (on squared distances)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--orig", required=True, help="a checkout of github.com/oravus/seqNet (its main.py)")
    p.add_argument("--variant", choices=sorted(VARIANTS), default="s5", help="s5 (S_5, w 5) or s1 (S_1, w 1)")
    p.add_argument("--dim", type=int, default=4096, help="descriptor dimension D = outDims (default 4096, the paper's)")
    p.add_argument("--repeats", type=int, default=1, help="epochs of each side, interleaved (default 1)")
    p.add_argument("--threads", type=int, default=2, help="torch threads of both sides, the original's loader workers")
    p.add_argument("--sides", default="orig,seqnet", help="which sides to run (default both: orig,seqnet)")
    p.add_argument("--workdir", required=True, help="folder for the prepared inputs and runs (kept; reused)")
    p.add_argument("--json", metavar="FILE", help="also write the result as JSON")
    p.add_argument("--orig-batches", type=int, metavar="N",
                   help="stop the original at its first progress line at or past batch N and extrapolate its epoch: "
                        "mining cache + training span x all batches / N (at D = 4096 an epoch takes hours)")
    return p.parse_args(argv)


def route_pair(n: int, dim: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(summer, winter)`` ``[n, dim]`` float32 unit rows: a route (each frame a small random step from the
    last, so nearby frames are similar and far ones unrelated) and the same route seen again with noise."""
    rng = np.random.default_rng(seed)
    steps = rng.standard_normal((n, dim), dtype=np.float32) * np.float32(0.35 / np.sqrt(dim))
    ref = np.empty((n, dim), np.float32)
    cur = rng.standard_normal(dim, dtype=np.float32)
    for t in range(n):
        cur /= np.linalg.norm(cur)
        ref[t] = cur
        cur = cur + steps[t]
    q = ref + rng.standard_normal((n, dim), dtype=np.float32) * np.float32(2.0 / np.sqrt(dim))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return ref, q


def struct_dir(orig: Path) -> Path:
    """The original's own struct files (its repository's ``structFiles/``), checked."""
    d = orig / "structFiles"
    missing = [s for s in STRUCTS if not (d / s).is_file()]
    if missing or not (orig / "main.py").is_file():
        raise SystemExit(f"{orig} is not a seqNet checkout (missing main.py or structFiles/{missing})")
    return d


def prepare(work: Path, orig: Path, dim: int, threads: int) -> tuple[Path, Path]:
    """The original's working directory (its layout) and the seqnet dataset of the same arrays."""
    base = work / f"d{dim}"
    run_dir, ds = base / "orig", base / "seqnet-dataset"
    desc = run_dir / "data" / "descData" / "netvlad-pytorch"
    if not (desc / "nordland-clean-winter.npy").exists():
        desc.mkdir(parents=True, exist_ok=True)
        ref, q = route_pair(N_FRAMES, dim)
        np.save(desc / "nordland-clean-summer.npy", ref)
        np.save(desc / "nordland-clean-winter.npy", q)
        del ref, q
    link = run_dir / "structFiles"
    if not link.exists():
        link.symlink_to(struct_dir(orig).resolve())
    if not (ds / "dataset.json").exists():
        cmd = [sys.executable, "-m", "seqnet", "-q", "dataset", "from-seqnet", "--preset", "nordland",
               "--ref-desc", str(desc / "nordland-clean-summer.npy"),
               "--query-desc", str(desc / "nordland-clean-winter.npy"), "--out", str(ds), "--overwrite"]
        for s in STRUCTS[:2]:
            cmd += ["--db", str(link / s)]
        subprocess.run(cmd, check=True, env=environment(threads))
    return run_dir, ds


def environment(threads: int) -> dict[str, str]:
    """Both sides: this checkout's seqnet, ``threads`` threads for every library, unbuffered output."""
    out = {**os.environ, "PYTHONPATH": str(REPO / "src"), "PYTHONUNBUFFERED": "1"}
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        out[name] = str(threads)
    return out


def tree_cpu(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` and its live descendants, plus the children
    it has reaped (the original's data-loader workers are its children), from ``/proc``."""
    tick = os.sysconf("SC_CLK_TCK")
    stats: dict[int, tuple[int, float, float]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # after the name: state ppid ... utime(14) stime(15) cutime(16) cstime(17), 1-based from pid
        stats[int(entry.name)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / tick,
                                  (int(fields[13]) + int(fields[14])) / tick)
    tree, frontier = {pid}, [pid]
    while frontier:
        parent = frontier.pop()
        kids = [p for p, (pp, _, _) in stats.items() if pp == parent and p not in tree]
        tree.update(kids)
        frontier += kids
    own = sum(stats[p][1] for p in tree if p in stats)
    return own + (stats[pid][2] if pid in stats else 0.0)


def timed_span(cmd: list[str], cwd: Path, threads: int, start: str, end: str,
               stream: str) -> tuple[float, float, str]:
    """Run ``cmd``; the wall and CPU seconds (:func:`tree_cpu`) between the first line of ``stream`` (stdout /
    stderr) matching ``start`` and the first later one matching ``end`` (regular expressions), taken as the
    lines arrive; and that end line."""
    proc = subprocess.Popen(cmd, cwd=cwd, env=environment(threads), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, bufsize=1)
    other: list[str] = []
    watched, drained = (proc.stdout, proc.stderr) if stream == "stdout" else (proc.stderr, proc.stdout)
    drain = threading.Thread(target=lambda: other.extend(drained), daemon=True)
    drain.start()
    t0 = t1 = c0 = c1 = None
    last, tail = "", []
    for line in watched:
        now = time.perf_counter()
        tail = (tail + [line])[-40:]
        if t0 is None and re.search(start, line):
            t0, c0 = now, tree_cpu(proc.pid)
        elif t0 is not None and t1 is None and re.search(end, line):
            t1, c1, last = now, tree_cpu(proc.pid), line.strip()
    proc.wait()
    drain.join()
    if proc.returncode or t0 is None or t1 is None:
        raise SystemExit(f"failed ({proc.returncode}; span found: {t0 is not None}, {t1 is not None}): "
                         f"{' '.join(cmd)}\n{''.join(tail)}\n{''.join(other[-40:])}")
    return t1 - t0, c1 - c0, last


def orig_cmd(orig: Path, variant: str, dim: int, threads: int) -> list[str]:
    v = VARIANTS[variant]
    return [sys.executable, str((orig / "main.py").resolve()), "--mode", "train", "--pooling", "seqnet",
            "--dataset", "nordland-sw", "--seqL", str(v["seqL"]), "--w", str(v["w"]), "--outDims", str(dim),
            "--expName", f"w{v['w']}", "--nocuda", "--nEpochs", "1", "--evalEvery", "2", "--threads", str(threads)]


def seqnet_cmd(ds: Path, out: Path, variant: str, dim: int, threads: int) -> list[str]:
    v = VARIANTS[variant]
    return [sys.executable, "-m", "seqnet", "--threads", str(threads), "train", "--dataset", str(ds), "--out",
            str(out), "--seq-len", str(v["seqL"]), "--w", str(v["w"]), "--out-dims", str(dim), "--epochs", "1",
            "--val-split", "none", "--cache-refresh", "0", "--margin", f"{MARGIN ** 0.5:.6f}", "--seed", "123",
            "--no-progress", "-v"]


def run_orig(orig: Path, run_dir: Path, variant: str, dim: int, threads: int) -> tuple[float, float, str]:
    secs, cpu, line = timed_span(orig_cmd(orig, variant, dim, threads), run_dir, threads, r"^===> Training model",
                            r"^===> Epoch 1 Complete", "stdout")
    shutil.rmtree(run_dir / "data" / "runs", ignore_errors=True)
    return secs, cpu, line


def run_orig_partial(orig: Path, run_dir: Path, variant: str, dim: int, threads: int,
                     batches: int) -> tuple[float, float, str]:
    """The original's epoch extrapolated from its first ``batches`` batches (wall; CPU seconds of the part run):
    the mining cache (``===> Training model`` .. its first ``Allocated:`` line) plus the training span up to the
    progress line ``==> Epoch[1](n/total)`` with n >= ``batches``, times total / n. The process is then killed."""
    proc = subprocess.Popen(orig_cmd(orig, variant, dim, threads), cwd=run_dir, env=environment(threads),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    t0 = t1 = None
    try:
        for line in proc.stdout:
            now = time.perf_counter()
            if t0 is None and line.startswith("===> Training model"):
                t0 = now
            elif t0 is not None and t1 is None and line.startswith("Allocated:"):
                t1 = now
            m = re.search(r"==> Epoch\[1\]\((\d+)/(\d+)\)", line)
            if t1 is not None and m and int(m.group(1)) >= batches:
                n, total = int(m.group(1)), int(m.group(2))
                cpu = tree_cpu(proc.pid)
                epoch = (t1 - t0) + (now - t1) * total / n
                return epoch, cpu, (f"extrapolated: mining cache {t1 - t0:.1f} s, {n} of {total} batches in "
                                    f"{now - t1:.1f} s")
    finally:
        proc.kill()
        proc.wait()
        shutil.rmtree(run_dir / "data" / "runs", ignore_errors=True)
        for left in (run_dir / "data" / "cache").glob("train_feat_cache_*.hdf5"):  # the original deletes its own at
            left.unlink(missing_ok=True)  # the end of an epoch; a killed one leaves it (N x D floats)
    raise SystemExit(f"the original ended before batch {batches} (cache seen: {t1 is not None})")


def run_seqnet(ds: Path, work: Path, variant: str, dim: int, threads: int) -> tuple[float, float, str]:
    out = work / f"seqnet-run-{variant}-{dim}"
    shutil.rmtree(out, ignore_errors=True)
    secs, cpu, line = timed_span(seqnet_cmd(ds, out, variant, dim, threads), REPO, threads, r"training S_\d",
                                 r"epoch 1/1: loss", "stderr")
    shutil.rmtree(out, ignore_errors=True)
    return secs, cpu, line


def measure(args: argparse.Namespace) -> dict:
    """Best epoch (wall and CPU seconds) of each side over ``args.repeats`` interleaved runs, with both sides' last
    summary lines."""
    orig, work = Path(args.orig), Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    run_dir, ds = prepare(work, orig, args.dim, args.threads)
    sides = [s.strip() for s in args.sides.split(",") if s.strip()]
    best = {s: float("inf") for s in sides}
    cpu = dict(best)
    lines = {}
    for _ in range(args.repeats):
        for side in sides:
            if side == "orig" and args.orig_batches:
                secs, used, lines[side] = run_orig_partial(orig, run_dir, args.variant, args.dim, args.threads,
                                                           args.orig_batches)
            elif side == "orig":
                secs, used, lines[side] = run_orig(orig, run_dir, args.variant, args.dim, args.threads)
            else:
                secs, used, lines[side] = run_seqnet(ds, work, args.variant, args.dim, args.threads)
            best[side], cpu[side] = min(best[side], secs), min(cpu[side], used)
            print(f"{side}: {secs:.1f} s wall, {used:.1f} s CPU ({lines[side]})", file=sys.stderr, flush=True)
    res = {"variant": VARIANTS[args.variant]["name"], "dim": args.dim, "threads": args.threads,
           "repeats": args.repeats, "epoch_s": best, "epoch_cpu_s": cpu, "lines": lines,
           "load_average": os.getloadavg()[0]}
    if args.orig_batches:
        res["orig_extrapolated_from_batches"] = args.orig_batches  # its CPU seconds are of the part run only
    if len(sides) == 2:
        res["ratio"] = best["orig"] / best["seqnet"]
        if not args.orig_batches:
            res["cpu_ratio"] = cpu["orig"] / cpu["seqnet"]
    return res


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.orig_batches is not None and args.orig_batches < 1:
        raise SystemExit(f"--orig-batches must be at least 1, got {args.orig_batches}")
    res = measure(args)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
