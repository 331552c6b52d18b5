"""What the guarded boundary costs: the same commands run by two source trees, side by side.

Runs ``seqnet eval`` and ``seqnet localize`` (the whole command a user types, start-up included) with the
``--before`` tree (e.g. a checkout of the commit before the security package) and this tree, interleaved
A B A B, same threads, best of ``--reps``; checks that both give the same figures, and prints a Markdown
table of the wall times and their ratio, with the load average.

    git worktree add ../before c8989d8
    seqnet benchmark nordland64 --data ../shared/data/nordland64 --out /tmp/n64    # dataset and models
    python benchmarks/bench_boundary.py --before ../before/src --data /tmp/n64 --reps 5
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1] / "src"


def commands(data: Path, work: Path, tag: str, common: list[str]) -> dict[str, tuple[list[str], Path]]:
    """The measured commands (argv after ``python -m seqnet``) and the JSON file each writes its figures to
    (``common``: ``--common-queries`` for a tree whose single-frame methods would otherwise score every frame,
    so both trees do the same work)."""
    ds, models = data / "dataset", [data / "models" / "seqnet.pt", data / "models" / "s1.pt"]
    m = [a for p in models for a in ("--model", str(p))]
    ev, loc = work / f"eval-{tag}.json", work / f"track-{tag}.csv"
    return {"eval": (["--threads", "2", "-q", "eval", "--dataset", str(ds), "--split", "test", *m, *common,
                      "--json", str(ev)], ev),
            "localize": (["--threads", "1", "-q", "localize", "--dataset", str(ds), "--split", "test", *m,
                          "--method", "hvpr", "--out", str(loc)], loc.with_suffix(".json"))}


def run(src: Path, argv: list[str]) -> float:
    env = {**os.environ, "PYTHONPATH": str(src)}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "seqnet", *argv], env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def common_queries(src: Path) -> list[str]:
    """``["--common-queries"]`` when the tree ``src`` has the flag (one query set for every method), else []."""
    help_text = subprocess.run([sys.executable, "-m", "seqnet", "eval", "--help"], env={**os.environ,
                               "PYTHONPATH": str(src)}, check=True, capture_output=True, text=True).stdout
    return ["--common-queries"] if "--common-queries" in help_text else []


def figures(path: Path) -> dict:
    """The R@K / summary figures of an output (eval's methods, localize's summary), for comparison."""
    data = json.loads(path.read_text())
    if "methods" in data:
        return {m: {k: v for k, v in r.items() if k.startswith(("recall@", "auc"))} for m, r in data["methods"].items()}
    s = data["summary"]
    return {k: s[k] for k in ("frames", "answered", "recall@1", "auc") if k in s}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="the src/ folder of the tree to compare with")
    ap.add_argument("--data", required=True, help="a `seqnet benchmark nordland64 --out` folder (dataset, models)")
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    trees = {"before": Path(args.before).resolve(), "after": HERE}
    common = {tag: common_queries(src) for tag, src in trees.items()}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        times: dict[tuple[str, str], list[float]] = {}
        outs = {}
        for _ in range(args.reps):
            for tag, src in trees.items():  # interleaved: A B A B
                for name, (argv, out) in commands(Path(args.data), work, tag, common[tag]).items():
                    times.setdefault((name, tag), []).append(run(src, argv))
                    outs[(name, tag)] = figures(out)
        load = os.getloadavg()
    print(f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f}; best of {args.reps}, interleaved\n")
    print("| command | before (s) | after (s) | after / before | same figures |")
    print("|---|---|---|---|---|")
    for name in ("eval", "localize"):
        a, b = min(times[(name, "before")]), min(times[(name, "after")])
        same = outs[(name, "before")] == outs[(name, "after")]
        print(f"| {name} | {a:.2f} | {b:.2f} | {b / a:.3f} | {'yes' if same else 'NO'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
