"""``seqnet benchmark nordland64``: the real-data benchmark (train S_L / S_1, evaluate every method);
``seqnet benchmark timing``: the compute-time table and its sweep over map sizes."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import ConfigError
from ..describe import DESCRIBERS, DescribeConfig
from ..describe.config import Size, check_size
from ..eval.select import FUSE_TOP_KS, FUSE_WEIGHTS, TOP_KS
from ..maps import MapConfig
from ..maps.config import DTYPES
from ..pipelines.nordland64 import Nordland64Config, main
from ..pipelines.nordland64.config import SELECTABLE
from ..pipelines.nordland64.run import selection_notes
from ..pipelines.timing import BIG_SIZES, TimingConfig
from ..report.guidance import format_notes, learned_below_baseline
from ..report.tables import format_table, ground_truth_text
from ..search.ann import ANN_INDEXES
from ..security.text import shown
from ..sequence.descriptors import DESCRIPTOR_ALIASES, SEQUENCE_DESCRIPTORS
from ..train.losses import LOSSES
from . import COMMANDS
from .common import (
    add_device,
    add_recall_denominator,
    index_range,
    int_list,
    non_negative_float,
    non_negative_int,
    parse_list,
    positive_float,
    positive_int,
    speed_range,
)

_D, _T = Nordland64Config(), TimingConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("benchmark", help=COMMANDS["benchmark"])
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    n = bsub.add_parser("nordland64", help="Nordland 64x32 frames, summer vs winter: train, select on val, test",
                        description="Describe the nordland64 frames, train S_L and S_1 on the train range (epochs "
                                    "chosen on val), evaluate every method on the test range; writes results.json, "
                                    "results.md, recall_at_k.png and config.json to --out. Defaults: "
                                    "seqnet.pipelines.nordland64.Nordland64Config (docs/benchmark_nordland64.md).")
    n.add_argument("--data", required=True, metavar="PATH", help="nordland64 folder (summer/, winter/, clean list)")
    n.add_argument("--out", required=True, metavar="DIR", help="output folder (descriptor cache, models, results)")
    add_overwrite(n, "results, descriptors and models")
    for split in ("train", "val", "test"):
        a, b = getattr(_D, f"{split}_range")
        n.add_argument(f"--{split}-range", type=index_range, metavar="A:B", help=f"{split} places (default {a}:{b})")
    add_descriptor_options(n)
    n.add_argument("--patch", type=non_negative_int,
                   help=f"pixels patch-normalisation size (default {_D.describe.patch}; 8 = SeqSLAM's)")
    n.add_argument("--seq-len", type=positive_int,
                   help=f"sequence length L of S_L, evaluation and SeqMatch (default {_D.seq_len})")
    n.add_argument("--w", type=positive_int, help=f"S_L temporal kernel width (default {_D.train.w})")
    n.add_argument("--epochs", type=positive_int, help=f"training epochs of S_L and S_1 (default {_D.train.epochs})")
    n.add_argument("--pca-dims", type=non_negative_int,
                   help=f"PCA size before training (0: none; default {_D.pca_dims})")
    n.add_argument("--top-k", type=positive_int, help=f"HVPR shortlist size (default: chosen on val among "
                   f"{','.join(map(str, TOP_KS))}, ties to {_D.top_k})")
    n.add_argument("--seed", type=non_negative_int, help=f"training seed (default {_D.train.seed})")
    n.add_argument("--fuse-weight", type=non_negative_float,
                   help=f"λ of hvpr-fused's score matcher/L_m + λ·d(S_L) (default: chosen on val among "
                        f"{','.join(f'{w:g}' for w in FUSE_WEIGHTS)}, ties to {_D.fuse_weight:g})")
    n.add_argument("--fuse-top-k", type=positive_int, help=f"hvpr-fused's shortlist size (default: chosen on val "
                   f"among {','.join(map(str, FUSE_TOP_KS))}, ties to {_D.fuse_top_k})")
    n.add_argument("--s1-loss", choices=list(LOSSES), help=f"loss of S_1 (default {_D.train_s1.loss}; seqmatch: "
                   "SeqMatchNet-style, on SeqMatch scores of L-frame windows)")
    n.add_argument("--s1-margin", type=positive_float, help=f"margin of S_1's loss (default {_D.train_s1.margin:g})")
    n.add_argument("--speed-augment", type=speed_range, metavar="VMIN:VMAX", help="train S_L on query windows "
                   "re-sampled at random speeds in VMIN:VMAX (default "
                   + (":".join(f"{v:g}" for v in _D.train.speed_augment) if _D.train.speed_augment else "off")
                   + "; 1:1 turns it off)")
    n.add_argument("--query-speed", type=speed_range, metavar="A:B",
                   help="re-sample the winter (query) traverse of the val and test ranges at A to B times the "
                        "reference speed (e.g. 0.5:2; frames dropped or repeated, positions kept; seeded) and also "
                        "evaluate the velocity-robust methods (default: as filmed)")
    add_recall_denominator(n, _D.recall_denominator)
    add_device(n)
    n.set_defaults(func=run_nordland64)
    register_timing(bsub)


def register_timing(bsub: argparse._SubParsersAction) -> None:
    """``seqnet benchmark timing``."""
    t = bsub.add_parser("timing", help="per-query cost of k-NN, SeqMatch (whole map, top K) and HVPR against N_db",
                        description="Time every method on synthetic maps (written to a temporary folder "
                                    "beside --out, deleted afterwards) or on the map of --dataset: one query at a "
                                    "time (mean ± std) and in a batch, descriptor comparisons, peak RSS (each map in "
                                    "a fresh process); writes results.json, results.md and timing.png to --out "
                                    "(docs/scale.md).")
    t.add_argument("--out", required=True, metavar="DIR", help="output folder")
    add_overwrite(t, "results.json, results.md and timing.png")
    t.add_argument("--sizes", type=int_list, metavar="N[,N...]", help=f"N_db of the synthetic maps (default "
                   f"{','.join(map(str, _T.sizes))}; --big: {','.join(map(str, BIG_SIZES))})")
    t.add_argument("--dims", type=int_list, metavar="D[,D...]", help=f"D (default {','.join(map(str, _T.dims))})")
    t.add_argument("--big", action="store_true", help="the large sweep (up to 1M at D=256, 100k at D=4096)")
    t.add_argument("--max-elements", type=positive_int, help=f"skip maps with N_db·D above (default {_T.max_elements})")
    t.add_argument("--seq-lens", type=int_list, metavar="L_M[,...]", help="L_m values (default 5)")
    t.add_argument("--top-ks", type=int_list, metavar="K[,...]", help="shortlist sizes K (default 20)")
    t.add_argument("--queries", type=positive_int, help=f"queries per figure (default {_T.queries})")
    t.add_argument("--repeats", type=positive_int, help=f"batch repeats, median reported (default {_T.repeats})")
    t.add_argument("--indexes", metavar="KIND[,...]", help=f"ANN shortlisters timed besides exact search "
                   f"({', '.join(ANN_INDEXES)}; default {','.join(_T.indexes)}; 'none' for none)")
    t.add_argument("--nlist", type=positive_int, help="IVF lists (default about 4·sqrt(N_db))")
    t.add_argument("--nprobe", type=positive_int, help=f"IVF lists visited (default {_T.ann.nprobe})")
    t.add_argument("--ef-search", type=positive_int, help=f"HNSW search breadth (default {_T.ann.ef_search})")
    t.add_argument("--dtype", choices=DTYPES, help="storage of the maps' descriptors (default float32)")
    t.add_argument("--no-float16-recall", action="store_true", help="skip R@1 with the map rounded to float16")
    t.add_argument("--noise", type=non_negative_float, help=f"synthetic query noise (default {_T.noise})")
    t.add_argument("--seed", type=non_negative_int, help=f"synthetic map seed (default {_T.seed})")
    t.add_argument("--dataset", help="time the map of this dataset's reference split instead (with --model)")
    t.add_argument("--model", action="append", default=[], metavar="CKPT", help="models of the --dataset map")
    t.add_argument("--shortlist", choices=[*SEQUENCE_DESCRIPTORS, *DESCRIPTOR_ALIASES],
                   help="--dataset map shortlist (default seqnet)")
    t.add_argument("--rerank", metavar="FRAMES+MATCHER", help="--dataset map re-ranker (default s1+seqmatch)")
    t.add_argument("--split", help="--dataset split (default: test when defined, else all)")
    t.add_argument("--device", default="cpu", help="torch device (default cpu; cuda for a GPU)")
    t.set_defaults(func=run_timing)


def add_descriptor_options(n: argparse.ArgumentParser) -> None:
    """``--descriptor``, ``--descriptors`` (the val choice's candidates) and ``--cnn-size``."""
    n.add_argument("--descriptor", choices=list(DESCRIBERS),
                   help="single-image descriptor (default: the one of --descriptors a model-free proxy prefers on "
                        "val, before training; with --descriptor, a CNN at its default size unless --cnn-size)")
    n.add_argument("--descriptors", metavar="NAME[,NAME...]",
                   help=f"the candidates of the val choice (default {','.join(_D.descriptors)}; the CNN ones at "
                        f"--cnn-size, left out when their backbone weights are not installed)")
    n.add_argument("--views", metavar="VIEW[,VIEW...]", help="with --descriptor: describe each frame in these "
                   "photometric views, concatenated (e.g. raw,equalize; default raw; docs/describe.md#views)")
    n.add_argument("--cnn-size", metavar="WxH", help="input size of a CNN --descriptor (netvlad, gmp, gem), e.g. "
                   "128x64 as the experiments use (default: the describer's own); without --descriptor, of the CNN "
                   f"candidates (default {_D.cnn_size[0]}x{_D.cnn_size[1]})")


def add_overwrite(p: argparse.ArgumentParser, what: str) -> None:
    """``--overwrite``: replace outputs in --out that this command did not write."""
    p.add_argument("--overwrite", action="store_true",
                   help=f"replace the {what} in --out even when this command did not write them (default: refuse)")


def timing_config(args: argparse.Namespace) -> TimingConfig:
    """The timing settings from the flags (unset flags keep the defaults)."""
    indexes = None
    if args.indexes is not None:
        indexes = () if args.indexes.strip() == "none" else tuple(parse_list([args.indexes]))
    return _T.merge(sizes=args.sizes or (BIG_SIZES if args.big else None), dims=args.dims,
                      max_elements=args.max_elements, seq_lens=args.seq_lens, top_ks=args.top_ks,
                      queries=args.queries, repeats=args.repeats, indexes=indexes, device=args.device,
                      ann={"nlist": args.nlist, "nprobe": args.nprobe, "ef_search": args.ef_search}, dtype=args.dtype,
                      float16_recall=False if args.no_float16_recall else None, noise=args.noise, seed=args.seed)


def run_timing(args: argparse.Namespace) -> int:
    conf = timing_config(args)
    mconf = MapConfig().merge(shortlist=args.shortlist, rerank=args.rerank, split=args.split)
    from ..pipelines.timing.run import main as timing_main

    path = timing_main(conf, args.out, args.dataset, args.model, mconf, overwrite=args.overwrite)
    res = path.data  # what the stage wrote to results.json
    for e in res["maps"]:
        hv = {r["method"]: r["per_query_ms"] for r in e["rows"] if r["method"].startswith(("hvpr", "seqmatch_all"))}
        print(f"N_db {e['n_db']:>8,} D {e['dim']:>5}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in hv.items()))
    print(f"done in {res['seconds']:.0f} s; results in {shown(Path(args.out) / 'results.md')}")
    return 0


def _describe_of(args: argparse.Namespace) -> tuple[DescribeConfig | None, Size | None]:
    """The benchmark's describe settings (None: the default's, or the val choice's) and the CNN candidates' size
    (None: the default) from ``--descriptor``, ``--cnn-size``, ``--views`` and ``--patch``."""
    cnn = args.descriptor and args.descriptor != _D.describe.method
    if args.cnn_size and args.descriptor and not cnn:
        cnns = ", ".join(d for d in DESCRIBERS if d != _D.describe.method)
        raise ConfigError(f"--cnn-size is the input size of a CNN --descriptor ({cnns}), "
                          f"not of {args.descriptor}; hint: --descriptor netvlad, or leave --descriptor out")
    if args.views and not args.descriptor:
        raise ConfigError(f"--views goes with --descriptor (the val choice's candidates name their views, e.g. "
                          f"{next(d for d in _D.descriptors if '+' in d)}); hint: --descriptor netvlad --views "
                          f"{args.views}")
    views = {"views": args.views} if args.views else {}
    if args.cnn_size and not args.descriptor:
        cnn_size = check_size(args.cnn_size)
        if isinstance(cnn_size, str):
            raise ConfigError(f"--cnn-size must be WxH (e.g. 128x64), got {args.cnn_size!r}")
        return None, cnn_size
    if cnn:
        return DescribeConfig(method=args.descriptor, **views, **({"size": check_size(args.cnn_size)}
                                                                  if args.cnn_size else {})), None
    if args.patch is not None or views:
        return _D.describe.merge(**({"patch": args.patch} if args.patch is not None else {}), **views), None
    return None, None


def nordland64_config(args: argparse.Namespace) -> Nordland64Config:
    """The benchmark settings from the command-line flags (unset flags keep the defaults)."""
    no_augment = args.speed_augment == (1.0, 1.0)  # 1:1 is no augmentation, the default's (None: replace keeps it)
    train = {"seq_len": args.seq_len, "epochs": args.epochs, "seed": args.seed,
             "w": args.w or (min(_D.train.w, args.seq_len) if args.seq_len else None),
             "speed_augment": None if no_augment else args.speed_augment}
    s1 = {"epochs": args.epochs, "seed": args.seed, "loss": args.s1_loss, "margin": args.s1_margin,
          "match_len": args.seq_len}
    describe, cnn_size = _describe_of(args)
    return _D.merge(train_range=args.train_range, val_range=args.val_range, test_range=args.test_range,
                      describe=describe, seq_len=args.seq_len, top_k=args.top_k, device=args.device,
                      pca_dims=args.pca_dims, train=train,
                      train_s1=s1, query_speed=args.query_speed, fuse_weight=args.fuse_weight,
                      fuse_top_k=args.fuse_top_k, recall_denominator=args.recall_denominator,
                      select=chosen_on_val(args), cnn_size=cnn_size,
                      descriptors=tuple(parse_list([args.descriptors])) if args.descriptors else None)


def chosen_on_val(args: argparse.Namespace) -> tuple[str, ...]:
    """What the benchmark chooses on val: every setting of :data:`seqnet.pipelines.nordland64.config.SELECTABLE`
    whose flag was not given (an explicit flag always wins; ``--patch`` means pixels)."""
    given = {"descriptor": args.descriptor is not None or args.patch is not None, "top_k": args.top_k is not None,
             "fuse_top_k": args.fuse_top_k is not None, "fuse_weight": args.fuse_weight is not None}
    return tuple(k for k in SELECTABLE if not given[k])


def run_nordland64(args: argparse.Namespace) -> int:
    res = main(nordland64_config(args), args.data, args.out, overwrite=args.overwrite).data
    cfg, bench = res["config"], res["config"]["benchmark"]
    first = next(iter(res["methods"].values()))
    print(f"nordland64 test {bench['test_range'][0]}:{bench['test_range'][1]}: {first['queries']} queries, "
          f"{ground_truth_text(cfg)}, L={cfg['seq_len']}")
    print(format_table(res["methods"], cfg["ks"]))
    for line in selection_notes(res.get("selection", {})):
        print(shown(line))
    for line in format_notes(learned_below_baseline(res)):
        print(shown(line))
    print(f"done in {cfg['timings_s']['total']:.0f} s; results in {shown(Path(args.out) / 'results.md')}")
    return 0
