"""``seqnet demo``: the whole pipeline end to end on synthetic data (training included)."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

from ..pipelines.demo import DemoConfig, main
from ..pipelines.outputs import private_temp
from ..report.tables import format_table
from ..security.text import shown
from . import COMMANDS
from .common import add_device, int_at_least, non_negative_int, positive_int

_D = DemoConfig()
# without --out: <tmp>/seqnet-demo-run-…, held under its lock, removed after (or by the next demo); the "run-"
# keeps clear of older seqnets' unlocked seqnet-demo-XXXXXXXX folders, which may belong to a live run
TEMP_PREFIX = "seqnet-demo-run-"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help=COMMANDS["demo"],
                       description="Generate a synthetic route, train SeqNet S_L and S_1 on its train split (fast "
                                   f"demo settings: Adam, lr {_D.train.lr:g}, at most {_D.train.epochs} epochs, early "
                                   f"stop after {_D.train.patience} without a better val R@1), and print Recall@K of "
                                   "the baselines and the learned methods (seqnet, s1+seqmatch, hvpr = S_L shortlist "
                                   "+ S_1 SeqMatch) on the test split.")
    p.add_argument("--out", metavar="DIR", help="keep the dataset, training runs and results.json here "
                                                "(default: a temporary directory)")
    p.add_argument("--overwrite", action="store_true", help="replace dataset/, train_seqnet/, train_s1/ and "
                   "results.json in --out even when an earlier demo did not write them (default: refuse)")
    p.add_argument("--places", type=int_at_least(100), help=f"places along the synthetic route (default {_D.places})")
    p.add_argument("--seed", type=non_negative_int, help=f"random seed (default {_D.seed})")
    p.add_argument("--epochs", type=positive_int,
                   help=f"at most this many training epochs per model (default {_D.train.epochs}, early stopping)")
    p.add_argument("--no-train", action="store_true", help="evaluate the baselines only (no training)")
    # one torch thread unless --threads: the demo's tensors are small, and on a busy machine more threads
    # mostly wait for each other
    p.set_defaults(default_threads=1)
    add_device(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    conf = DemoConfig().merge(places=args.places, seed=args.seed, train_models=not args.no_train,
                                device=args.device, train={"epochs": args.epochs})
    with contextlib.nullcontext(Path(args.out)) if args.out else private_temp(TEMP_PREFIX) as where:
        res = main(conf, where if args.out else where / "demo", overwrite=args.overwrite).data
    m, cfg = res["methods"], res["config"]
    first = next(iter(m.values()))
    print(f"seqnet demo: synthetic route, test split, {first['queries']} queries, radius {cfg['radius']:g} m, "
          f"L={conf.seq_len}")
    if cfg["train_seconds"]:
        names = {"s1": "S_1", "seqnet": f"S_{conf.seq_len}"}
        times = ", ".join(f"{names[r]} {s:.1f} s" for r, s in cfg["train_seconds"].items())
        print(f"trained on the train split with the demo's fast settings (Adam, <= {conf.train.epochs} epochs): "
              f"{times}")
    print(format_table(m, cfg["ks"]))
    print(f"done in {cfg['demo_seconds']:.1f} s" + (f"; results in {shown(Path(args.out) / 'results.json')}"
                                                    if args.out else ""))
    return 0
