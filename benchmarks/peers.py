"""seqnet side by side with the tool a user would pick instead, on the same job (issue 34's table).

Every row runs the peer's way and seqnet's way on the same synthetic inputs, interleaved A B A B
(``--repeats`` times each), with the same threads, and keeps the best of each; the answers (Recall@1)
are compared. Whole-command rows run both as subprocesses (wall clock and peak RSS from ``wait4``).
The peers' ways are minimal scripts of this folder written after the peers' code (never copied):

- ``knn``: single-image k-NN, 20000 x 2048 database, 2000 queries, K = 20, whole command:
  ``benchmarks/peer_faiss_knn.py`` (VPR-methods-evaluation: faiss ``IndexFlatL2``) against
  ``seqnet eval --method single``;
- ``matrix10k`` / ``matrix1k``: evaluation of a given similarity matrix ``S [N_db, N_q]``:
  ``benchmarks/peer_numpy_pr.py`` (VPR_Tutorial: numpy best match + PR) against
  ``seqnet eval --distances S.npy --similarity --transposed``; wall and peak memory;
- ``help``: ``seqnet --help`` and ``seqnet eval --help`` against the 0.5 s goal (no peer);
- ``seqmatch``: whole-map SeqMatch against one bare GEMM of the same size (3000², D 4096, L 5), in one
  process per thread count (1 and 2);
- ``train``: one S_5 and one S_1 training epoch of the original seqNet ``main.py`` (a checkout named by
  ``--seqnet-orig``, run as it is from the data layout it reads) against ``seqnet train`` on the same
  descriptors and settings: ``benchmarks/peer_seqnet_train.py`` (D = 4096 × ``--scale``;
  ``--train-repeats`` epochs of each side, interleaved); without ``--seqnet-orig`` the row says it did
  not run and how to run it;
- ``hvpr``: the online per-frame step against its bytes-read floor is measured by
  ``benchmarks/bench_localize.py``; the row names that command.

Prints a Markdown table of ratios with the date, the machine, the load average before and after, and the
git commit. Usage::

    python benchmarks/peers.py                       # every row (several minutes on 2 cores)
    python benchmarks/peers.py --rows knn,help --repeats 3 --json out.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
ROWS = ("knn", "matrix10k", "matrix1k", "help", "seqmatch", "train", "hvpr")
TRAIN_COMMAND = ("git clone https://github.com/oravus/seqNet ORIG; pip install tensorboardX; "
                 "python benchmarks/peers.py --rows train --seqnet-orig ORIG")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rows", default=",".join(ROWS), help=f"rows to run, comma-separated (default all: {ROWS})")
    p.add_argument("--repeats", type=int, default=3, help="runs of each side, interleaved (default 3)")
    p.add_argument("--threads", type=int, default=2, help="threads of both sides (default 2)")
    p.add_argument("--scale", type=float, default=1.0, help="scale the row sizes (a quick check: 0.1)")
    p.add_argument("--workdir", help="folder for the generated inputs (default: a temporary one)")
    p.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    p.add_argument("--seqnet-orig", metavar="DIR", help="checkout of github.com/oravus/seqNet (the train row)")
    p.add_argument("--train-repeats", type=int, default=1, help="epochs of each side in the train row (default 1)")
    p.add_argument("--seqmatch-worker", type=int, help=argparse.SUPPRESS)  # internal: one thread count
    return p.parse_args(argv)


def env(threads: int) -> dict[str, str]:
    """The environment of both sides: this checkout's seqnet, the same threads for every library."""
    out = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        out[name] = str(threads)
    return out


def run_measured(cmd: list[str], threads: int) -> tuple[float, float, str]:
    """``(wall seconds, peak RSS GiB, stdout)`` of one subprocess (a failure is an error); the peak is this
    child's alone (``wait4``, not the running maximum of all children)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env(threads), text=True)
    out, err = proc.stdout.read(), proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{err[-2000:]}")
    return wall, usage.ru_maxrss / 2**20, out


def interleaved(a: list[str], b: list[str], threads: int, repeats: int) -> tuple[dict, dict]:
    """A B A B ...: the best wall and peak of each side, and each side's last stdout."""
    best = [{"wall": float("inf"), "peak": float("inf")}, {"wall": float("inf"), "peak": float("inf")}]
    for _ in range(repeats):
        for side, cmd in enumerate((a, b)):
            wall, peak, out = run_measured(cmd, threads)
            best[side] = {"wall": min(best[side]["wall"], wall), "peak": min(best[side]["peak"], peak), "out": out}
    return best[0], best[1]


def route(n: int, dim: int, rng: np.random.Generator, step: float = 0.35) -> np.ndarray:
    """``[n, dim]`` float32 unit rows along a route: each frame a small random step from the last."""
    x = np.empty((n, dim), np.float32)
    cur = rng.standard_normal(dim).astype(np.float32)
    for t in range(n):
        cur = cur / np.linalg.norm(cur)
        x[t] = cur
        cur = cur + step * rng.standard_normal(dim).astype(np.float32) / np.sqrt(dim)
    return x


def write_dataset(root: Path, n_ref: int, n_q: int, dim: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A seqnet dataset directory: a route of ``n_ref`` frames, ``n_q`` queries = noisy frames of it (radius 2)."""
    rng = np.random.default_rng(seed)
    ref = route(n_ref, dim, rng)
    src = np.sort(rng.choice(n_ref, n_q, replace=False))
    q = ref[src] + 0.5 * rng.standard_normal((n_q, dim)).astype(np.float32) / np.sqrt(dim)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    for side, x, pos in (("reference", ref, np.arange(n_ref)), ("query", q, src)):
        (root / side).mkdir(parents=True, exist_ok=True)
        np.save(root / side / "descriptors.npy", x)
        np.save(root / side / "positions.npy", pos.reshape(-1, 1).astype(np.float64))
    (root / "dataset.json").write_text(json.dumps({"format": "seqnet-dataset/1", "name": root.name, "radius": 2.0}))
    return ref, q


def seqnet_cmd(threads: int, *args: str) -> list[str]:
    return [sys.executable, "-m", "seqnet", "--threads", str(threads), "-q", *args]


def recall1_seqnet(path: Path) -> float:
    return float(json.loads(path.read_text())["methods"]["single"]["recall@1"])


def row_knn(work: Path, args: argparse.Namespace) -> list[dict]:
    n_ref, n_q = int(20000 * args.scale), int(2000 * args.scale)
    ds = work / "knn"
    if not (ds / "dataset.json").exists():
        write_dataset(ds, n_ref, n_q, 2048)
    peer = [sys.executable, str(HERE / "peer_faiss_knn.py"), str(ds), "--threads", str(args.threads)]
    ours = seqnet_cmd(args.threads, "eval", "--dataset", str(ds), "--method", "single", "--ks", "1,5,10,20",
                      "--json", str(work / "knn.json"), "--overwrite")
    p, s = interleaved(peer, ours, args.threads, args.repeats)
    ks = ("recall@1", "recall@5", "recall@10", "recall@20")  # every R@K compared, R@1 shown
    peer_out = json.loads(p["out"].strip().splitlines()[-1])
    ours_out = json.loads((work / "knn.json").read_text())["methods"]["single"]
    r_peer, r_ours = [peer_out[k] for k in ks], [ours_out[k] for k in ks]
    return [dict(job=f"single-image k-NN, {n_ref} x 2048 db, {n_q} queries, K 20, whole command",
                 peer="faiss IndexFlatL2 (VPR-methods-evaluation)", peer_value=p["wall"], ours_value=s["wall"],
                 unit="s", ratio=s["wall"] / p["wall"], goal=1.0,
                 answers=f"R@1 {r_peer[0]:.4f} / {r_ours[0]:.4f}, R@1,5,10,20 compared", same=r_peer == r_ours)]


def row_matrix(work: Path, args: argparse.Namespace, n: int) -> list[dict]:
    n = int(n * args.scale)
    ds = work / f"matrix{n}"
    if not (ds / "dataset.json").exists():
        ref, q = write_dataset(ds, n, n, 32, seed=1)
        np.save(ds / "S.npy", ref @ q.T)  # [N_db, N_q] similarities, VPR_Tutorial's orientation
    peer = [sys.executable, str(HERE / "peer_numpy_pr.py"), str(ds), str(ds / "S.npy")]
    ours = seqnet_cmd(args.threads, "eval", "--dataset", str(ds), "--distances", str(ds / "S.npy"), "--similarity",
                      "--transposed", "--method", "single", "--ks", "1", "--json", str(work / f"m{n}.json"),
                      "--overwrite")
    p, s = interleaved(peer, ours, args.threads, args.repeats)
    r_peer, r_ours = json.loads(p["out"].strip().splitlines()[-1])["recall@1"], recall1_seqnet(work / f"m{n}.json")
    job = f"evaluation of a given {n}² similarity matrix, whole command"
    same = abs(r_peer - r_ours) < 1e-12
    rows = [dict(job=job + " (wall)", peer="numpy best match + PR (VPR_Tutorial)", peer_value=p["wall"],
                 ours_value=s["wall"], unit="s", ratio=s["wall"] / p["wall"], goal=(p["wall"] + 0.3) / p["wall"],
                 answers=f"R@1 {r_peer:.4f} / {r_ours:.4f}", same=same)]
    if n >= 5000:
        rows.append(dict(job=job + " (peak memory)", peer="numpy best match + PR (VPR_Tutorial)",
                         peer_value=p["peak"], ours_value=s["peak"], unit="GiB", ratio=s["peak"] / p["peak"],
                         goal=1.0, answers=f"R@1 {r_peer:.4f} / {r_ours:.4f}", same=same))
    return rows


def row_help(work: Path, args: argparse.Namespace) -> list[dict]:
    rows = []
    for argv in (["--help"], ["eval", "--help"]):
        best = min(run_measured([sys.executable, "-m", "seqnet", *argv], args.threads)[0]
                   for _ in range(max(3, args.repeats)))
        rows.append(dict(job=f"seqnet {' '.join(argv)}", peer="goal 0.5 s", peer_value=0.5, ours_value=best,
                         unit="s", ratio=best / 0.5, goal=1.0, answers="-", same=None))
    return rows


def seqmatch_worker(threads: int, scale: float, repeats: int) -> None:
    """In its own process: best of ``repeats`` interleaved GEMM / whole-map SeqMatch on ``threads`` threads."""
    import torch

    from seqnet.matching.seqmatch import seqmatch

    torch.set_num_threads(threads)
    n = int(3000 * scale)
    rng = np.random.default_rng(0)
    q, r = (rng.standard_normal((n, 4096)).astype(np.float32) for _ in range(2))
    tq, tr = torch.from_numpy(q), torch.from_numpy(r)
    gemm = match = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        tq @ tr.T
        gemm = min(gemm, time.perf_counter() - start)
        start = time.perf_counter()
        seqmatch(q, r, 5, normalize=False)  # timed as given: no unit-norm check
        match = min(match, time.perf_counter() - start)
    print(json.dumps({"gemm": gemm, "seqmatch": match, "n": n}))


def row_seqmatch(work: Path, args: argparse.Namespace) -> list[dict]:
    rows = []
    for threads in (1, 2):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--seqmatch-worker", str(threads),
               "--scale", str(args.scale), "--repeats", str(args.repeats)]
        res = json.loads(run_measured(cmd, threads)[2].strip().splitlines()[-1])
        rows.append(dict(job=f"whole-map SeqMatch / bare GEMM, {res['n']}², D 4096, L 5, {threads} thread(s)",
                         peer="one GEMM of the same size", peer_value=res["gemm"], ours_value=res["seqmatch"],
                         unit="s", ratio=res["seqmatch"] / res["gemm"], goal=1.15, answers="-", same=None))
    return rows


def row_train(work: Path, args: argparse.Namespace) -> list[dict]:
    """S_5 and S_1: one epoch of the original ``main.py`` / one of ``seqnet train`` (benchmarks/peer_seqnet_train.py);
    the goal is seqnet at least 30x faster (ratio seqnet / peer <= 1/30)."""
    if not args.seqnet_orig:
        return [dict(job="S_L / S_1 training epoch vs the original seqNet main.py", peer="original seqNet main.py",
                     peer_value=None, ours_value=None, unit="", ratio=None, goal=None,
                     answers=f"not run (no --seqnet-orig): {TRAIN_COMMAND}", same=None)]
    dim, rows = max(16, int(4096 * args.scale)), []
    for variant in ("s5", "s1"):
        cmd = [sys.executable, str(HERE / "peer_seqnet_train.py"), "--orig", args.seqnet_orig, "--variant", variant,
               "--dim", str(dim), "--threads", str(args.threads), "--repeats", str(args.train_repeats),
               "--workdir", str(work / "train")]
        res = json.loads(run_measured(cmd, args.threads)[2].strip().splitlines()[-1])
        peer, ours = res["epoch_s"]["orig"], res["epoch_s"]["seqnet"]
        rows.append(dict(job=f"{res['variant']} training epoch, Nordland train split (15000 + 15000), D {dim}",
                         peer="original seqNet main.py --nEpochs 1", peer_value=peer, ours_value=ours, unit="s",
                         ratio=ours / peer, goal=1 / 30,
                         answers=f"{peer / ours:.1f}× faster wall, {res['cpu_ratio']:.1f}× less CPU "
                                 f"({res['epoch_cpu_s']['orig']:.0f} / {res['epoch_cpu_s']['seqnet']:.0f} s)",
                         same=None))
    return rows


def row_not_run(name: str) -> list[dict]:
    return [dict(job="online HVPR per frame / bytes-read floor", peer="bytes-read floor", peer_value=None,
                 ours_value=None, unit="", ratio=None, goal=None,
                 answers="not run here: python benchmarks/bench_localize.py --methods hvpr --threads 2", same=None)]


def machine() -> str:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} CPUs, {platform.system()} {platform.release()}"


def commit() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" (with uncommitted changes)" if dirty else "")


def fmt(v: float | None, unit: str) -> str:
    return "–" if v is None else f"{v:.2f} {unit}".strip()


def table(rows: list[dict]) -> str:
    lines = ["| job | peer (how) | peer | seqnet | seqnet / peer | goal | met | answers (peer / seqnet) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        met = "–" if r["ratio"] is None else ("yes" if r["ratio"] <= r["goal"] and r["same"] is not False else "no")
        met = "not run" if r["ratio"] is None else met
        ratio = "–" if r["ratio"] is None else f"{r['ratio']:.{2 if r['ratio'] >= 0.1 else 3}f}×"
        goal = "–" if r["goal"] is None else f"≤ {r['goal']:.{2 if r['goal'] >= 0.1 else 3}f}×"
        same = "" if r["same"] is None else (" (identical)" if r["same"] else " (DIFFERENT)")
        lines.append(f"| {r['job']} | {r['peer']} | {fmt(r['peer_value'], r['unit'])} | "
                     f"{fmt(r['ours_value'], r['unit'])} | {ratio} | {goal} | {met} | {r['answers']}{same} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.seqmatch_worker:
        seqmatch_worker(args.seqmatch_worker, args.scale, args.repeats)
        return 0
    wanted = [r.strip() for r in args.rows.split(",") if r.strip()]
    unknown = sorted(set(wanted) - set(ROWS))
    if unknown:
        raise SystemExit(f"unknown rows {unknown}; choose from {ROWS}")
    load_before = os.getloadavg()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="seqnet-peers-") as tmp:
        work = Path(args.workdir or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in wanted:
            if name == "knn":
                rows += row_knn(work, args)
            elif name in ("matrix10k", "matrix1k"):
                rows += row_matrix(work, args, 10000 if name == "matrix10k" else 1000)
            elif name == "help":
                rows += row_help(work, args)
            elif name == "seqmatch":
                rows += row_seqmatch(work, args)
            elif name == "train":
                rows += row_train(work, args)
            else:
                rows += row_not_run(name)
    load_after = os.getloadavg()
    head = (f"{datetime.date.today().isoformat()} · {machine()} · commit {commit()} · {args.threads} threads · "
            f"best of {args.repeats}, interleaved · load average {load_before[0]:.2f} before, "
            f"{load_after[0]:.2f} after")
    print(head + "\n\n" + table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps({"header": head, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
