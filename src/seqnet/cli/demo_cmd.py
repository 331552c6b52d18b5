"""``seqnet demo``: the whole pipeline end to end on synthetic data."""

from __future__ import annotations

import argparse

from ..demo import run_demo
from ..report import format_table
from ..utils import write_json_atomic
from .common import add_device, positive_int


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run every method on synthetic data and print the comparison table")
    p.add_argument("--out", metavar="DIR", help="keep the dataset and results here (default: temporary)")
    p.add_argument("--places", type=positive_int, default=1000, help="places along the synthetic route (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_device(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    ev = run_demo(args.out, places=args.places, seed=args.seed, device=args.device)
    m = ev.results["methods"]
    first = next(iter(m.values()))
    print(f"seqnet demo: synthetic route, test split, {first['queries']} queries, radius {ev.radius:g} m, L=5")
    print(format_table(m, ev.results["config"]["ks"]))
    print(f"done in {ev.results['config']['demo_seconds']:.1f} s")
    if args.out:
        write_json_atomic(f"{args.out}/results.json", ev.results)
    return 0
