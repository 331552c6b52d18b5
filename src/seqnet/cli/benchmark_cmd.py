"""``seqnet benchmark nordland64``: the real-data benchmark (train S_L / S_1, evaluate every method)."""

from __future__ import annotations

import argparse

from .common import add_device, index_range, positive_int

DESCRIPTORS = ("pixels", "gem", "gmp", "netvlad")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("benchmark", help="run a benchmark on real data (nordland64)")
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    n = bsub.add_parser("nordland64", help="Nordland 64x32 frames, summer vs winter: train, select on val, test",
                        description="Describe the nordland64 frames, train S_L and S_1 on the train range (epochs "
                                    "chosen on val), evaluate every method on the test range; writes results.json, "
                                    "results.md, recall_at_k.png and config.json to --out. Defaults: "
                                    "seqnet.presets.BENCHMARKS['nordland64'] (docs/benchmark_nordland64.md).")
    n.add_argument("--data", required=True, metavar="PATH", help="nordland64 folder (summer/, winter/, clean list)")
    n.add_argument("--out", required=True, metavar="DIR", help="output folder (descriptor cache, models, results)")
    n.add_argument("--train-range", type=index_range, metavar="A:B", help="train places (default 0:1650)")
    n.add_argument("--val-range", type=index_range, metavar="A:B", help="validation places (default 1660:1930)")
    n.add_argument("--test-range", type=index_range, metavar="A:B", help="test places (default 1940:2761)")
    n.add_argument("--descriptor", choices=DESCRIPTORS, help="single-image descriptor (default pixels)")
    n.add_argument("--patch", type=int, help="pixels patch-normalisation size (default: preset; 8 = SeqSLAM's)")
    n.add_argument("--seq-len", type=positive_int, help="sequence length L of S_L, evaluation and SeqMatch (default 5)")
    n.add_argument("--w", type=positive_int, help="S_L temporal kernel width (default 5)")
    n.add_argument("--epochs", type=positive_int, help="training epochs of S_L and S_1 (default: preset)")
    n.add_argument("--pca-dims", type=int, help="PCA size before training (0: none; default: preset)")
    n.add_argument("--top-k", type=positive_int, help="HVPR shortlist size (default 20)")
    add_device(n)
    n.set_defaults(func=run_nordland64)


def nordland64_overrides(args: argparse.Namespace) -> dict:
    """Benchmark config overrides from the command-line flags (None: keep the default)."""
    from ..data.presets import BENCHMARKS

    base = BENCHMARKS["nordland64"]
    train = {k: v for k, v in (("seq_len", args.seq_len), ("w", args.w), ("epochs", args.epochs)) if v is not None}
    if args.seq_len is not None and args.w is None:
        train["w"] = min(base["train"]["w"], args.seq_len)
    conf = {
        "train_range": list(args.train_range) if args.train_range else None,
        "val_range": list(args.val_range) if args.val_range else None,
        "test_range": list(args.test_range) if args.test_range else None,
        "descriptor": args.descriptor, "seq_len": args.seq_len, "top_k": args.top_k,
        "device": args.device, "pca_dims": args.pca_dims,
        "train": {**base["train"], **train} if train else None,
    }
    if args.descriptor and args.descriptor != "pixels":
        conf["descriptor_options"] = {"size": "auto"}  # CNNs: the describer's default input size
    elif args.patch is not None:
        conf["descriptor_options"] = {**base["descriptor_options"], "patch": args.patch}
    return conf


def run_nordland64(args: argparse.Namespace) -> int:
    from ..pipelines.nordland64 import main
    from ..report import format_table

    ev = main(nordland64_overrides(args), args.data, args.out)
    cfg = ev.results["config"]
    first = next(iter(ev.results["methods"].values()))
    print(f"nordland64 test {cfg['benchmark']['test_range'][0]}:{cfg['benchmark']['test_range'][1]}: "
          f"{first['queries']} queries, radius {ev.radius:g}, L={cfg['seq_len']}")
    print(format_table(ev.results["methods"], cfg["ks"]))
    print(f"done in {cfg['timings_s']['total']:.0f} s; results in {args.out}/results.md")
    return 0
