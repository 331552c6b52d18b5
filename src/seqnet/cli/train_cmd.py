"""``seqnet train``: train SeqNet S_L (or S_1 with ``--seq-len 1 --w 1``) on a dataset's train split."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from ..core.errors import ConfigError
from ..core.log import logger
from ..sequence.checkpoints import read_checkpoint
from ..sequence.windows import WINDOW_MODES
from ..train.config import OPTIMIZERS, RESUME_OVERRIDABLE, TrainConfig
from ..train.distributed import env_world
from ..train.joint import S1_LOSS, is_joint, main_joint, s1_config
from ..train.loop import main
from ..train.losses import LOSSES
from ..train.run import resume_config
from ..train.rundir import check_new
from ..train.source import check_splits
from ..train.watch import inactive_epochs
from . import COMMANDS
from .common import (
    add_allow_mismatch,
    add_device,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    speed_range,
)

_D = TrainConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train", help=COMMANDS["train"],
        description="Train SeqNet on the train split of a dataset, validating (Recall@1/5/10/20) on its val split "
                    "after every epoch. Writes RUN/last.pt, RUN/best.pt (best val R@1), RUN/config.json and "
                    "TensorBoard logs in RUN/. Defaults are the paper's (SGD lr 1e-4, momentum 0.9, wd 1e-3, "
                    "lr x0.5 every 50 epochs, margin 0.3, batch 16, 10 hard negatives of 1000 sampled). "
                    "Distributed: torchrun --nproc-per-node N -m seqnet train ... (see docs/training.md).")
    p.add_argument("--dataset", metavar="DIR", help="seqnet dataset directory (default with --resume: the run's)")
    p.add_argument("--out", metavar="RUN", help="run directory to create (default with --resume: the resumed run)")
    p.add_argument("--resume", metavar="RUN", help="continue the run in RUN exactly (RUN/last.pt); "
                   "only --epochs, --patience and --device may change")
    m = p.add_argument_group("model")
    m.add_argument("--seq-len", type=positive_int, help=f"sequence length L (default {_D.seq_len}; S_1: 1)")
    m.add_argument("--w", type=positive_int,
                   help=f"temporal filter width, 1 <= w <= L (default {_D.w}, or L when L < {_D.w}; S_1: 1)")
    m.add_argument("--out-dims", type=positive_int, help="output descriptor dimension (default: the input's)")
    m.add_argument("--window", choices=WINDOW_MODES, help=f"window position (default {_D.window})")
    o = p.add_argument_group("optimisation")
    o.add_argument("--optimizer", choices=list(OPTIMIZERS), help=f"optimiser (default {_D.optimizer})")
    o.add_argument("--lr", type=positive_float, help=f"learning rate (default {_D.lr:g})")
    o.add_argument("--momentum", type=non_negative_float, help=f"SGD momentum (default {_D.momentum})")
    o.add_argument("--weight-decay", type=non_negative_float, help=f"weight decay (default {_D.weight_decay:g})")
    o.add_argument("--lr-step", type=positive_int,
                   help=f"multiply the lr by --lr-gamma every N epochs (default {_D.lr_step})")
    o.add_argument("--lr-gamma", type=positive_float, help=f"lr decay factor (default {_D.lr_gamma})")
    o.add_argument("--margin", type=positive_float, help=f"triplet margin on L2 distances (default {_D.margin})")
    o.add_argument("--batch-size", type=positive_int, help=f"queries per batch (default {_D.batch_size})")
    o.add_argument("--epochs", type=positive_int, help=f"number of epochs (default {_D.epochs})")
    o.add_argument("--patience", type=positive_int, help="stop after N epochs without a better val R@1 (default: off)")
    o.add_argument("--seed", type=non_negative_int, help=f"random seed (default {_D.seed})")
    t = p.add_argument_group("triplets")
    t.add_argument("--pos-radius", type=positive_float, help="positives lie within this distance (default: the "
                   "dataset's pos_radius, else its localisation radius; not used with explicit positives)")
    t.add_argument("--neg-radius", type=positive_float, help="negatives lie beyond this distance (with explicit "
                   "positives: from every positive of the query, between reference positions; default: the "
                   "dataset's neg_radius, else 4 x the positive radius)")
    t.add_argument("--n-negatives", type=positive_int, help=f"hard negatives per query (default {_D.n_negatives})")
    t.add_argument("--n-neg-sample", type=positive_int,
                   help=f"negatives sampled per query to mine from (default {_D.n_neg_sample})")
    t.add_argument("--cache-refresh", type=non_negative_int, help="recompute the mining descriptors every N queries "
                   f"(default {_D.cache_refresh}; 0: once per epoch)")
    t.add_argument("--train-split", help=f"split to train on (default {_D.train_split}; 'all': the whole dataset)")
    t.add_argument("--val-split", help=f"split to validate on (default {_D.val_split}; 'none': no validation, "
                   "best.pt = last)")
    add_learning(p)
    add_guide(p)
    add_allow_mismatch(p)
    add_device(p)
    p.set_defaults(func=run)


def add_guide(p: argparse.ArgumentParser) -> None:
    """The flags the training plan advises (--pca) and the stop on epochs without an active triplet."""
    g = p.add_argument_group("guide (the plan logged before training says when to reduce D)")
    g.add_argument("--pca", type=positive_int, metavar="D", help="reduce the descriptors to D dimensions first, by a "
                   "PCA fitted on the train split only, into DATASET-pcaD beside the dataset (reused when present; "
                   "evaluate on it); advised when D > 4096 or above the training frames (the plan logged says)")
    g.add_argument("--stop-inactive", type=non_negative_int, metavar="N", help="stop after N epochs in a row without "
                   f"an active triplet (the model no longer learns; default {_D.stop_inactive}, 0: never)")


def add_learning(p: argparse.ArgumentParser) -> None:
    """The loss, speed augmentation and joint-training flags."""
    t = p.add_argument_group("loss and augmentation")
    t.add_argument("--loss", choices=list(LOSSES), help="loss: " + "; ".join(f"{k}: {v.help}" for k, v in
                   LOSSES.items()) + f" (default {_D.loss})")
    t.add_argument("--match-len", type=positive_int, help="L_m, the SeqMatch window of --loss seqmatch / vseqmatch "
                   f"(default {_D.match_len})")
    t.add_argument("--speed-augment", type=speed_range, metavar="VMIN:VMAX", help="re-sample every training query "
                   "window at a random speed in VMIN:VMAX each epoch (frame offsets round(t*v); e.g. 0.5:2; "
                   "default: off)")
    j = p.add_argument_group("joint training (S_L and S_1 for HVPR in one run folder: RUN/seqnet, RUN/s1)")
    j.add_argument("--joint", action="store_true", help="train S_L with the settings given and S_1 beside it "
                   "(seq_len = w = 1, --s1-loss, --s1-lr, --s1-margin)")
    j.add_argument("--s1-loss", choices=list(LOSSES), default=S1_LOSS,
                   help=f"loss of the S_1 model of --joint (default {S1_LOSS})")
    j.add_argument("--s1-lr", type=positive_float, help="learning rate of the S_1 model of --joint (default --lr)")
    j.add_argument("--s1-margin", type=positive_float, help="margin of the S_1 model of --joint (default --margin)")


_KEYS = tuple(f.name for f in dataclasses.fields(TrainConfig) if f.name != "device")  # one flag each


def default_w(seq_len: int | None, w: int | None) -> int | None:
    """``--w`` as given, else at most L: ``--seq-len 1`` (S_1) or 2 without ``--w`` trains with w = L (the
    default w does not fit in a shorter window); None: the default."""
    if w is None and seq_len is not None and seq_len < _D.w:
        logger.info("--seq-len %d without --w: w = %d (w <= L)", seq_len, seq_len)
        return seq_len
    return w


def run(args: argparse.Namespace) -> int:
    changes = {k: getattr(args, k) for k in _KEYS}
    if not args.resume:
        changes["w"] = default_w(args.seq_len, args.w)
    if args.device != "auto" or not args.resume:
        changes["device"] = args.device
    if args.pca is not None:
        args.dataset = _reduced(args, TrainConfig().merge(**changes))
    if args.joint or (args.resume and is_joint(args.resume)):
        return _run_joint(args, changes)
    conf = resume_config(args.resume, **changes) if args.resume else TrainConfig().merge(**changes)
    run_dir = main(conf, args.dataset, args.out, args.resume, allow_mismatch=args.allow_mismatch)
    if env_world().is_rank0:  # under torchrun, rank 0 alone wrote the run and reports it
        _print_summary(run_dir)
    return 0


def _reduced(args: argparse.Namespace, conf: TrainConfig) -> str:
    """``--pca D``: the dataset reduced by a PCA fitted on the train split (:mod:`seqnet.pipelines.pca`; what it
    costs ``conf``'s val split measured and said), after the checks that can refuse the run on its positions and run
    directory (nothing written before them)."""
    if args.resume:
        raise ConfigError("--pca applies when a run starts; a resumed run continues on the dataset it recorded "
                          "(drop --pca)")
    if args.dataset is None:
        raise ConfigError("--pca needs --dataset DIR")
    from ..data.io import load_dataset
    from ..pipelines.pca import main as reduce_main

    src = load_dataset(args.dataset)
    check_splits(src, conf)
    if args.out is not None:
        check_new(Path(args.out))
    return str(reduce_main(args.dataset, args.pca, args.train_split or _D.train_split, conf, src))


def _run_joint(args: argparse.Namespace, changes: dict) -> int:
    """``--joint``: S_L and S_1 into RUN/seqnet and RUN/s1 (or resume such a run)."""
    if args.resume:
        given = [k for k, v in changes.items() if v is not None and k not in RESUME_OVERRIDABLE]
        given += [k for k in ("s1_lr", "s1_margin") if getattr(args, k) is not None]
        if given:
            raise ConfigError(f"cannot change {given[0]!r} when resuming the joint run {args.resume}: it continues "
                              f"with its stored settings; only {', '.join(RESUME_OVERRIDABLE)} may change")
        dirs = main_joint(None, None, args.dataset, args.out, args.resume, args.allow_mismatch,
                          {k: changes.get(k) for k in RESUME_OVERRIDABLE})
    else:
        if args.loss is not None and LOSSES[args.loss].framewise:  # S_1-only losses
            raise ConfigError(f"--loss {args.loss} with --joint: the S_L model trains with the triplet loss "
                              "(hint: --s1-loss for the S_1 model)")
        conf = TrainConfig().merge(**changes)
        s1 = s1_config(conf, args.s1_loss, args.s1_lr, args.s1_margin)
        dirs = main_joint(conf, s1, args.dataset, args.out, None, args.allow_mismatch)
    if env_world().is_rank0:
        for run_dir in dirs.values():
            _print_summary(run_dir)
        print(f"HVPR: seqnet eval --dataset {_dataset_of(dirs['seqnet'])} --method hvpr --shortlist-model "
              f"{dirs['seqnet'] / 'best.pt'} --rerank-model {dirs['s1'] / 'best.pt'}")
    return 0


def _dataset_of(run_dir: Path) -> str:
    """The dataset path a run recorded in its config.json ('DIR' when it recorded none)."""
    from ..security.jsonfile import read_json_object

    path = read_json_object(run_dir / "config.json", "run configuration").get("dataset_path")
    return path if isinstance(path, str) and path else "DIR"


def _print_summary(run_dir: Path) -> None:
    last = read_checkpoint(run_dir / "last.pt")
    model, best = last["model"], float(last["best_score"])
    role = "S_1" if model["seq_len"] == 1 and model["w"] == 1 else f"S_{model['seq_len']}"
    score = "n/a (no validation)" if math.isnan(best) else f"{best:.4f}"
    best_epoch = last.get("best_epoch", last["train_state"]["best_epoch"])
    print(f"trained {role} (w={model['w']}, D={model['in_dims']}->{model['out_dims']}) to epoch {last['epoch']}"
          f"{_stopped(last)}; best val R@1 {score} at epoch {best_epoch}")
    print(f"checkpoints: {run_dir / 'best.pt'} (best), {run_dir / 'last.pt'} (last)")
    flag = "--rerank-model" if role == "S_1" else f"--seq-len {model['seq_len']} --shortlist-model"
    print(f"evaluate: seqnet eval --dataset {last.get('dataset_path') or 'DIR'} {flag} {run_dir / 'best.pt'}")


def _stopped(last: dict) -> str:
    """`` of N`` when the run reached its last epoch, else why it stopped before it."""
    conf, state = last.get("config") or {}, last["train_state"]
    epochs = conf.get("epochs")
    if not isinstance(epochs, int) or last["epoch"] >= epochs:
        return f" of {epochs}" if isinstance(epochs, int) else ""
    inactive = inactive_epochs(state.get("history") or [])
    if conf.get("stop_inactive") and inactive >= conf["stop_inactive"]:
        return f" of {epochs} (stopped: no active triplet for {inactive} epochs)"
    return f" of {epochs} (early stop: no better val R@1 for {state.get('bad_epochs')} epochs)"
