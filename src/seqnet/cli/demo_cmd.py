"""``seqnet demo``: the whole pipeline end to end on synthetic data (training included)."""

from __future__ import annotations

import argparse

from ..files import write_json_atomic
from ..pipelines.demo import DEMO_PLACES, DEMO_SEQ_LEN, run_demo
from ..report import format_table
from .common import add_device, positive_int


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="train S_L and S_1 on synthetic data and compare every method",
                       description="Generate a synthetic route, train SeqNet S_L and S_1 on its train split (fast "
                                   "demo settings: Adam, a few epochs), and print Recall@K of the baselines and the "
                                   "learned methods (seqnet, s1+seqmatch, hvpr = S_L shortlist + S_1 SeqMatch) on the "
                                   "test split.")
    p.add_argument("--out", metavar="DIR", help="keep the dataset, training runs and results here (default: temporary)")
    p.add_argument("--places", type=positive_int, default=DEMO_PLACES,
                   help=f"places along the synthetic route (default {DEMO_PLACES})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--epochs", type=positive_int,
                   help="training epochs per model (default: the demo's, 15, with early stopping)")
    p.add_argument("--no-train", action="store_true", help="evaluate the baselines only (no training)")
    # one torch thread unless --threads: the demo's tensors are small, and on a busy machine more threads
    # mostly wait for each other
    p.set_defaults(default_threads=1)
    add_device(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    ev = run_demo(args.out, places=args.places, seed=args.seed, device=args.device, epochs=args.epochs,
                  train_models=not args.no_train)
    m, cfg = ev.results["methods"], ev.results["config"]
    first = next(iter(m.values()))
    print(f"seqnet demo: synthetic route, test split, {first['queries']} queries, radius {ev.radius:g} m, "
          f"L={DEMO_SEQ_LEN}")
    if cfg["train_seconds"]:
        names = {"s1": "S_1", "seqnet": f"S_{DEMO_SEQ_LEN}"}
        times = ", ".join(f"{names[r]} {s:.1f} s" for r, s in cfg["train_seconds"].items())
        print(f"trained on the train split with the demo's fast settings (Adam, <= {cfg['demo_train']['epochs']} "
              f"epochs): {times}")
    print(format_table(m, cfg["ks"]))
    print(f"done in {cfg['demo_seconds']:.1f} s")
    if args.out:
        write_json_atomic(f"{args.out}/results.json", ev.results)
    return 0
