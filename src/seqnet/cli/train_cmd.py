"""``seqnet train``: train SeqNet S_L (or S_1 with ``--seq-len 1 --w 1``) on a dataset's train split."""

from __future__ import annotations

import argparse
import math

from ..train.loop import TRAIN_CONFIG_DEFAULTS, main
from ..utils import set_threads
from .common import add_device, non_negative_int, positive_float, positive_int

_D = TRAIN_CONFIG_DEFAULTS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train", help="train a SeqNet model (S_L, or S_1 with --seq-len 1 --w 1) with triplet loss",
        description="Train SeqNet on the train split of a dataset, validating (Recall@1/5/10/20) on its val split "
                    "after every epoch. Writes RUN/last.pt, RUN/best.pt (best val R@1), RUN/config.json and "
                    "TensorBoard logs in RUN/. Defaults are the paper's (SGD lr 1e-4, momentum 0.9, wd 1e-3, "
                    "lr x0.5 every 50 epochs, margin 0.3, batch 16, 10 hard negatives of 1000 sampled).")
    p.add_argument("--dataset", metavar="DIR", help="seqnet dataset directory (default with --resume: the run's)")
    p.add_argument("--out", metavar="RUN", help="run directory to create (default with --resume: the resumed run)")
    p.add_argument("--resume", metavar="RUN", help="continue the run in RUN exactly (RUN/last.pt); "
                   "only --epochs, --patience and --device may change")
    m = p.add_argument_group("model")
    m.add_argument("--seq-len", type=positive_int, help=f"sequence length L (default {_D['seq_len']}; S_1: 1)")
    m.add_argument("--w", type=positive_int, help=f"temporal filter width, 1 <= w <= L (default {_D['w']}; S_1: 1)")
    m.add_argument("--out-dims", type=positive_int, help="output descriptor dimension (default: the input's)")
    m.add_argument("--window", choices=["centred", "causal"], help="window position (default centred)")
    o = p.add_argument_group("optimisation")
    o.add_argument("--optimizer", choices=["sgd", "adam"], help="optimiser (default sgd)")
    o.add_argument("--lr", type=positive_float, help=f"learning rate (default {_D['lr']:g})")
    o.add_argument("--momentum", type=float, help=f"SGD momentum (default {_D['momentum']})")
    o.add_argument("--weight-decay", type=float, help=f"weight decay (default {_D['weight_decay']:g})")
    o.add_argument("--lr-step", type=positive_int,
                   help=f"multiply the lr by --lr-gamma every N epochs (default {_D['lr_step']})")
    o.add_argument("--lr-gamma", type=positive_float, help=f"lr decay factor (default {_D['lr_gamma']})")
    o.add_argument("--margin", type=positive_float, help=f"triplet margin on L2 distances (default {_D['margin']})")
    o.add_argument("--batch-size", type=positive_int, help=f"queries per batch (default {_D['batch_size']})")
    o.add_argument("--epochs", type=positive_int, help=f"number of epochs (default {_D['epochs']})")
    o.add_argument("--patience", type=positive_int, help="stop after N epochs without a better val R@1 (default: off)")
    o.add_argument("--seed", type=int, help=f"random seed (default {_D['seed']})")
    t = p.add_argument_group("triplets")
    t.add_argument("--pos-radius", type=positive_float, help="positives lie within this distance (default: the "
                   "dataset's pos_radius, else its localisation radius)")
    t.add_argument("--neg-radius", type=positive_float, help="negatives lie beyond this distance (default: the "
                   "dataset's neg_radius, else 4 x the positive radius)")
    t.add_argument("--n-negatives", type=positive_int, help=f"hard negatives per query (default {_D['n_negatives']})")
    t.add_argument("--n-neg-sample", type=positive_int,
                   help=f"negatives sampled per query to mine from (default {_D['n_neg_sample']})")
    t.add_argument("--cache-refresh", type=non_negative_int, help="recompute the mining descriptors every N queries "
                   f"(default {_D['cache_refresh']}; 0: once per epoch)")
    t.add_argument("--train-split", help="split to train on (default train; 'all': the whole dataset)")
    t.add_argument("--val-split", help="split to validate on (default val; 'none': no validation, best.pt = last)")
    add_device(p)
    p.add_argument("--threads", type=positive_int, help="CPU threads for torch (default: torch's)")
    p.set_defaults(func=run)


_KEYS = ("seq_len", "w", "out_dims", "window", "optimizer", "lr", "momentum", "weight_decay", "lr_step", "lr_gamma",
         "margin", "batch_size", "epochs", "patience", "seed", "pos_radius", "neg_radius", "n_negatives",
         "n_neg_sample", "cache_refresh", "train_split", "val_split")


def run(args: argparse.Namespace) -> int:
    set_threads(args.threads)
    config = {k: getattr(args, k) for k in _KEYS if getattr(args, k) is not None}
    if args.device != "auto" or not args.resume:
        config["device"] = args.device
    result = main({"dataset": args.dataset, "out": args.out, "resume": args.resume, "config": config})
    role = "S_1" if result.model.seq_len == 1 and result.model.w == 1 else f"S_{result.model.seq_len}"
    best = "n/a (no validation)" if math.isnan(result.best_score) else f"{result.best_score:.4f}"
    print(f"trained {role} (w={result.model.w}, D={result.model.in_dims}->{result.model.out_dims}) for "
          f"{result.epoch} epochs; best val R@1 {best} at epoch {result.best_epoch}")
    print(f"checkpoints: {result.out_dir / 'best.pt'} (best), {result.out_dir / 'last.pt'} (last)")
    flag = "--rerank-model" if role == "S_1" else f"--seq-len {result.model.seq_len} --shortlist-model"
    data = result.cfg.get("dataset_path", "DIR")
    print(f"evaluate: seqnet eval --dataset {data} {flag} {result.out_dir / 'best.pt'}")
    return 0
