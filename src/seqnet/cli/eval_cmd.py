"""``seqnet eval``: evaluate methods on a dataset directory and print/save Recall@K."""

from __future__ import annotations

import argparse

from ..dataset_io import load_dataset
from ..evaluate import evaluate
from ..methods import valid_methods
from ..report import format_table
from ..utils import write_json_atomic
from .common import add_device, parse_list, positive_float, positive_int


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate place-recognition methods (Recall@K) on a dataset",
                       description="Evaluate methods on a seqnet dataset directory. Methods: "
                       + ", ".join(valid_methods()))
    p.add_argument("--dataset", required=True, help="seqnet dataset directory (see docs/dataset_format.md)")
    p.add_argument("--method", "--methods", dest="methods", action="append", metavar="M[,M...]",
                   help="methods to run (repeatable or comma-separated; default: all that need no model)")
    p.add_argument("--seq-len", type=positive_int, help="window length L (default: the S_L model's, else 5)")
    p.add_argument("--window", choices=["centred", "causal"], help="window position (default centred)")
    p.add_argument("--radius", type=positive_float, help="localisation radius (default: the dataset's)")
    p.add_argument("--extra-radius", type=positive_float, action="append", default=[],
                   help="also report at this radius")
    p.add_argument("--split", help="split to evaluate: train, val, test or all (default: test when defined, else all)")
    p.add_argument("--top-k", type=positive_int, help="HVPR shortlist size (default 20)")
    p.add_argument("--shortlist", help="HVPR shortlister for 'hvpr': single, s1, smoothing, delta, seqnet")
    p.add_argument("--rerank", help="HVPR re-ranking descriptor: raw, s1, delta")
    p.add_argument("--model", action="append", default=[], metavar="CKPT",
                   help="trained model checkpoint (S_L → 'seqnet', S_1 → 's1'); repeatable")
    p.add_argument("--shortlist-model", metavar="CKPT", help="S_L checkpoint used by 'seqnet' and HVPR shortlisting")
    p.add_argument("--rerank-model", metavar="CKPT",
                   help="S_1 checkpoint used by 's1', 's1+seqmatch' and HVPR re-ranking")
    p.add_argument("--backend", choices=["torch", "faiss"], help="k-NN backend (default torch)")
    p.add_argument("--json", metavar="FILE", help="write results (and resolved config) as JSON")
    add_device(p)
    p.set_defaults(func=run)


def load_models(args: argparse.Namespace) -> dict:
    """Models by role from ``--model``, ``--shortlist-model`` and ``--rerank-model``."""
    paths = list(args.model) + [x for x in (args.shortlist_model, args.rerank_model) if x]
    if not paths:
        return {}
    from ..checkpoints import load_model, model_role

    models = {}
    for path in args.model:
        model = load_model(path)  # an original checkpoint without flags.json: use --shortlist-model + --seq-len
        models[model_role(model)] = model
    if args.shortlist_model:
        models["seqnet"] = load_model(args.shortlist_model, seq_len=args.seq_len)
    if args.rerank_model:
        models["s1"] = load_model(args.rerank_model)
    return models


def run(args: argparse.Namespace) -> int:
    ds = load_dataset(args.dataset)
    split = args.split or ("test" if "test" in ds.splits else "all")
    models = load_models(args)
    if args.seq_len is None and "seqnet" in models:  # evaluate with the S_L model's own window length
        args.seq_len = models["seqnet"].seq_len
    methods = parse_list(args.methods, valid_methods(), "method") or None
    if methods is None:
        needs = {"s1": "s1", "seqnet": "seqnet", "s1+seqmatch": "s1"}
        order = ["single", "s1", "smoothing", "delta", "seqnet",
                 "raw+seqmatch", "s1+seqmatch", "delta+seqmatch", "hvpr"]
        methods = [m for m in order if needs.get(m, "") in models or m not in needs]
        if args.seq_len == 1:  # Delta descriptors need L >= 2: leave out the default methods that use them
            shortlister = args.shortlist or ("seqnet" if "seqnet" in models else "delta")
            hvpr_delta = "delta" in (shortlister, args.rerank)
            methods = [m for m in methods if m not in ("delta", "delta+seqmatch") and not (m == "hvpr" and hvpr_delta)]
    config = {"methods": methods, "seq_len": args.seq_len, "window": args.window, "radius": args.radius,
              "extra_radii": args.extra_radius, "top_k": args.top_k, "shortlist": args.shortlist,
              "rerank": args.rerank, "backend": args.backend, "device": args.device, "split": split}
    ev = evaluate(ds.split(split), config, models)
    ev.results["config"]["dataset_path"] = str(args.dataset)
    print(f"dataset {ds.name} [{split}], radius {ev.radius:g} {ds.position_unit}, "
          f"L={ev.results['config']['seq_len']} ({ev.results['config']['window']})")
    print(format_table(ev.results["methods"], ev.results["config"]["ks"]))
    first = next(iter(ev.results["methods"].values()))
    print(f"{first['queries']} queries evaluated; {first['no_full_window']} without a full window, "
          f"{first['no_positive']} without a reference within the radius (left out)")
    if args.json:
        write_json_atomic(args.json, ev.results)
    return 0
