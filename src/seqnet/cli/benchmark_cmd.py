"""``seqnet benchmark nordland64``: the real-data benchmark (train S_L / S_1, evaluate every method)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..describe import DESCRIBERS, DescribeConfig
from ..pipelines.nordland64 import Nordland64Config, main
from ..report import format_table
from .common import add_device, index_range, non_negative_int, positive_int

_D = Nordland64Config()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("benchmark", help="run a benchmark on real data (nordland64)")
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    n = bsub.add_parser("nordland64", help="Nordland 64x32 frames, summer vs winter: train, select on val, test",
                        description="Describe the nordland64 frames, train S_L and S_1 on the train range (epochs "
                                    "chosen on val), evaluate every method on the test range; writes results.json, "
                                    "results.md, recall_at_k.png and config.json to --out. Defaults: "
                                    "seqnet.pipelines.nordland64.Nordland64Config (docs/benchmark_nordland64.md).")
    n.add_argument("--data", required=True, metavar="PATH", help="nordland64 folder (summer/, winter/, clean list)")
    n.add_argument("--out", required=True, metavar="DIR", help="output folder (descriptor cache, models, results)")
    for split in ("train", "val", "test"):
        a, b = getattr(_D, f"{split}_range")
        n.add_argument(f"--{split}-range", type=index_range, metavar="A:B", help=f"{split} places (default {a}:{b})")
    n.add_argument("--descriptor", choices=list(DESCRIBERS),
                   help=f"single-image descriptor (default {_D.describe.method}; others at their default size)")
    n.add_argument("--patch", type=non_negative_int,
                   help=f"pixels patch-normalisation size (default {_D.describe.patch}; 8 = SeqSLAM's)")
    n.add_argument("--seq-len", type=positive_int,
                   help=f"sequence length L of S_L, evaluation and SeqMatch (default {_D.seq_len})")
    n.add_argument("--w", type=positive_int, help=f"S_L temporal kernel width (default {_D.train.w})")
    n.add_argument("--epochs", type=positive_int, help=f"training epochs of S_L and S_1 (default {_D.train.epochs})")
    n.add_argument("--pca-dims", type=non_negative_int,
                   help=f"PCA size before training (0: none; default {_D.pca_dims})")
    n.add_argument("--top-k", type=positive_int, help=f"HVPR shortlist size (default {_D.top_k})")
    n.add_argument("--seed", type=non_negative_int, help=f"training seed (default {_D.train.seed})")
    n.add_argument("--query-speed", type=speed_range, metavar="A:B",
                   help="re-sample the winter (query) traverse of the val and test ranges at A to B times the "
                        "reference speed (e.g. 0.5:2; frames dropped or repeated, positions kept; seeded) and also "
                        "evaluate the velocity-robust methods (default: as filmed)")
    add_device(n)
    n.set_defaults(func=run_nordland64)


def nordland64_config(args: argparse.Namespace) -> Nordland64Config:
    """The benchmark settings from the command-line flags (unset flags keep the defaults)."""
    train = {"seq_len": args.seq_len, "epochs": args.epochs, "seed": args.seed,
             "w": args.w or (min(_D.train.w, args.seq_len) if args.seq_len else None)}
    describe = None
    if args.descriptor and args.descriptor != _D.describe.method:
        describe = DescribeConfig(method=args.descriptor)
    elif args.patch is not None:
        describe = _D.describe.replace(patch=args.patch)
    return _D.replace(train_range=args.train_range, val_range=args.val_range, test_range=args.test_range,
                      describe=describe, seq_len=args.seq_len, top_k=args.top_k, device=args.device,
                      pca_dims=args.pca_dims, train=train,
                      train_s1={"epochs": args.epochs, "seed": args.seed}, query_speed=args.query_speed)


def speed_range(text: str) -> tuple[float, float]:
    """argparse type: ``A:B`` with ``0 < A <= B`` (query speed relative to the reference)."""
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (e.g. 0.5:2), got {text!r}") from None
    if not 0 < a <= b < float("inf"):
        raise argparse.ArgumentTypeError(f"expected 0 < A <= B, got {text!r}")
    return a, b


def run_nordland64(args: argparse.Namespace) -> int:
    res = json.loads(Path(main(nordland64_config(args), args.data, args.out)).read_text(encoding="utf-8"))
    cfg, bench = res["config"], res["config"]["benchmark"]
    first = next(iter(res["methods"].values()))
    print(f"nordland64 test {bench['test_range'][0]}:{bench['test_range'][1]}: {first['queries']} queries, "
          f"radius {cfg['radius']:g}, L={cfg['seq_len']}")
    print(format_table(res["methods"], cfg["ks"]))
    print(f"done in {cfg['timings_s']['total']:.0f} s; results in {Path(args.out) / 'results.md'}")
    return 0
