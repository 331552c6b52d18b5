"""``seqnet experiment NAME``: the paper's tables and figures on the nordland64 data, each also named by its
table (``table-1`` … ``table-s3``; docs/experiments.md)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..describe.config import check_size
from ..pipelines.experiments import EXPERIMENTS, Experiment
from ..pipelines.experiments.descriptors import CNN_SIZE, DESCRIPTORS, describe_config
from ..pipelines.nordland64 import Nordland64Config
from ..security.inputs import read_text
from ..security.text import shown
from . import COMMANDS
from .common import (
    add_device,
    add_recall_denominator,
    index_range,
    int_list,
    non_negative_int,
    parse_list,
    positive_float,
    positive_int,
)

_D = Nordland64Config()


def seed_list(text: str) -> tuple[int, ...]:
    """argparse type: comma-separated integers >= 0 (e.g. ``0,1,2``)."""
    try:
        values = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers (e.g. 0,1,2), got {text!r}") from None
    if min(values) < 0:
        raise argparse.ArgumentTypeError(f"expected integers >= 0, got {text!r}")
    return values


# the options of one experiment: flag, config key, argparse type, help
OPTIONS: dict[str, list[tuple[str, str, Any, str]]] = {
    "comparison": [("--extra-methods", "extra_methods", str, "seqnet's rows after the paper's (default hvpr-fused)")],
    "compute-time": [("--queries", "queries", positive_int, "queries timed one at a time (default 30)")],
    "splits": [],
    "tables": [("--tables", "tables", str, "paper tables and figures (default I,II,III,S1,S2,S3,tsne)")],
    "reverse": [("--methods", "methods", str, "methods compared (comma-separated)")],
    "longer-sequences": [("--lengths", "lengths", int_list, "re-ranking lengths L_m (default 5,10,20)"),
                         ("--methods", "methods", str, "methods compared (comma-separated)")],
    "descriptors": [("--descriptors", "descriptors", str, "descriptors (default pixels,netvlad,gmp; also gem)"),
                    ("--cnn-size", "cnn_size", str, "CNN input size WxH (default 128x64)")],
    "tsne": [("--frames", "frames", positive_int, "the first N summer frames (default 1000)"),
             ("--perplexity", "perplexity", positive_float, "t-SNE perplexity (default 30)")],
    "seeds": [("--seeds", "seeds", seed_list, "training seeds (default 0,1,2)")],
}
LISTS = ("methods", "descriptors", "extra_methods", "tables")  # comma-separated names


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("experiment", help=COMMANDS["experiment"],
                       description="The paper's tables and figures on the nordland64 data, each also named by its "
                                   "table (table-1 ... table-s3), each writing results.json, results.md (the paper's "
                                   "table beside ours), its figure, report.html and config.json to --out "
                                   "(docs/experiments.md).")
    esub = p.add_subparsers(dest="experiment", metavar="NAME", required=True)
    for name, exp in EXPERIMENTS.items():
        e = esub.add_parser(name, aliases=[exp.alias] if exp.alias else [],
                            help=exp.summary,
                            description=f"{exp.summary}. Defaults: the nordland64 benchmark's "
                                        "(seqnet.pipelines.nordland64.Nordland64Config).")
        e.add_argument("--out", required=True, metavar="DIR", help="output folder")
        e.add_argument("--overwrite", action="store_true", help="replace outputs in --out (and cache entries) that "
                       "this experiment did not write (default: refuse)")
        if exp.data:
            _data_options(e, name, exp.own_data)
        if not exp.own_data:
            e.add_argument("--dataset", action=_NoDataset, nargs="?", help=argparse.SUPPRESS)
        for flag, key, kind, text in OPTIONS[name]:
            e.add_argument(flag, dest=key, type=kind, action="append" if key in LISTS else None, help=text)
        add_device(e)
        e.set_defaults(func=run, experiment_name=name)


class _NoDataset(argparse.Action):
    """``--dataset`` given to an experiment that runs only on the nordland64 data: refused naming those that take
    it (before argparse's "required: --data", which would not say why)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        own = [exp.alias or n for n, exp in EXPERIMENTS.items() if exp.own_data]
        name = parser.prog.split()[-1]
        exp = EXPERIMENTS[name]
        data = ("it runs on the nordland64 data only, given by --data (the nordland64 folder)" if exp.data else
                "it reads no data")
        parser.error(f"{exp.alias or name} takes no --dataset: {data}; only "
                     f"{', '.join(own)} take a seqnet dataset (--dataset)")


def _data_options(e: argparse.ArgumentParser, name: str, own_data: bool) -> None:
    """The options of an experiment on the nordland64 data: data (or a user's dataset), cache, ranges, training,
    descriptor."""
    e.add_argument("--data", required=not own_data, metavar="PATH",
                   help="nordland64 folder (summer/, winter/, clean list)" + (" (or --dataset)" if own_data else ""))
    if own_data:
        e.add_argument("--dataset", metavar="DIR", help="instead of --data: a seqnet dataset directory (its val and "
                       "test splits when it defines them, else all of it), evaluated with the --model checkpoints")
        e.add_argument("--model", action="append", default=[], metavar="CKPT",
                       help="with --dataset: an S_L or S_1 checkpoint (repeat; rows whose models are missing show –)")
    e.add_argument("--cache", metavar="DIR", help="descriptors and models cache (default --out; a benchmark's "
                                                  "--out reuses its descriptors and models)")
    for split in ("train", "val", "test"):
        a, b = getattr(_D, f"{split}_range")
        e.add_argument(f"--{split}-range", type=index_range, metavar="A:B", help=f"{split} places (default {a}:{b})")
    e.add_argument("--epochs", type=positive_int, help=f"training epochs (default {_D.train.epochs})")
    e.add_argument("--pca-dims", type=non_negative_int, help=f"PCA before training (default {_D.pca_dims})")
    e.add_argument("--seed", type=non_negative_int, help=f"training seed (default {_D.train.seed})")
    add_recall_denominator(e, _D.recall_denominator)
    if name != "descriptors":
        e.add_argument("--descriptor", choices=DESCRIPTORS, help="single-image descriptor (default pixels, the "
                       "benchmark's; others are cached in CACHE/descriptors/NAME)")
        e.add_argument("--cnn-size", help="CNN input size WxH of --descriptor netvlad/gmp/gem (default 128x64)")


def experiment_config(args: argparse.Namespace) -> Any:
    """The experiment's settings from the flags (unset flags keep the defaults)."""
    name = args.experiment_name
    exp: Experiment = EXPERIMENTS[name]
    own = {}
    for _, key, _, _ in OPTIONS[name]:
        value = getattr(args, key)
        own[key] = (tuple(parse_list(value)) or None) if key in LISTS else value
    if not exp.data:  # compute-time: the timing sweep's settings
        return exp.config().merge(timing={"device": "cpu" if args.device == "auto" else args.device, **own})
    train = {"epochs": args.epochs, "seed": args.seed}
    describe = None
    if name != "descriptors" and (args.descriptor or args.cnn_size):
        size = check_size(args.cnn_size) if args.cnn_size else CNN_SIZE
        describe = describe_config(args.descriptor or _D.describe.method, size)
    bench = _D.merge(train_range=args.train_range, val_range=args.val_range, test_range=args.test_range,
                       pca_dims=args.pca_dims, device=args.device, train=train, train_s1=train, describe=describe,
                       recall_denominator=args.recall_denominator)
    return exp.config().merge(benchmark=bench, **own)


def run(args: argparse.Namespace) -> int:
    conf = experiment_config(args)
    inputs = vars(args)  # only the options the experiment has (data, cache, dataset, model)
    path = EXPERIMENTS[args.experiment_name].start(conf, args.out, inputs.get("data"), inputs.get("cache"),
                                                    inputs.get("dataset"), inputs.get("model", ()), args.overwrite)
    out = Path(path).parent
    md = read_text(out / "results.md", 64 << 20, "results.md")  # names from a user's dataset: shown escaped
    print("\n".join(shown(line) for line in md.splitlines()))
    files = [f for f in ("results.json", "results.md", "report.html") if (out / f).is_file()]
    print(f"results in {shown(out)} ({', '.join(files)})")
    return 0
