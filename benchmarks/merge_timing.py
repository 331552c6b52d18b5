"""Merge several ``seqnet benchmark timing`` results into one sweep: ``results.json``, ``results.md``, ``timing.png``.

Maps measured in more than one run are taken from the last run that has them.

Usage::

    python benchmarks/merge_timing.py OUT/timing OUT/timing-256 OUT/timing-4096 --out OUT/sweep
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seqnet.pipelines.timing.report import markdown, plot


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", help="output folders of seqnet benchmark timing")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    runs = [json.loads((Path(r) / "results.json").read_text()) for r in args.runs]
    maps = {}
    for run in runs:
        for e in run["maps"]:
            maps[(e["n_db"], e["dim"])] = e
    merged = {**runs[-1], "maps": [maps[k] for k in sorted(maps)], "seconds": sum(r["seconds"] for r in runs),
              "merged_from": args.runs}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(merged, indent=2))
    (out / "results.md").write_text(markdown(merged))
    plot(merged, out / "timing.png")


if __name__ == "__main__":
    main()
