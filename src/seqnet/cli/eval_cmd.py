"""``seqnet eval``: evaluate methods on a dataset directory and print/save Recall@K."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import ConfigError
from ..core.log import counted, ordinal
from ..eval.config import EvalConfig
from ..methods.grammar import DEFAULT_METHODS, FUSED_TOP_K, valid_methods
from ..metrics.consistency import CONFIDENCES
from ..report.guidance import format_notes, learned_below_baseline, unmatched
from ..report.tables import format_table, ground_truth_text
from ..search.knn import KNN_BACKENDS
from ..security.text import shown
from ..sequence.windows import WINDOW_MODES
from . import COMMANDS
from .common import (
    add_allow_mismatch,
    add_calibration_options,
    add_device,
    add_distances,
    add_recall_denominator,
    calibrated_result,
    check_calibration_options,
    check_distances,
    check_method_options,
    int_list,
    missed_target_note,
    non_negative_float,
    parse_list,
    positive_float,
    positive_int,
)
from .dataset_cmd.resample import add_resample_options

if TYPE_CHECKING:
    from ..report.html import ReportConfig

_D = EvalConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help=COMMANDS["eval"],
                       description="Evaluate methods on a seqnet dataset directory. Methods: "
                       + ", ".join(valid_methods()) + ", or hvpr-<shortlister>:<frames>+<matcher> "
                       "(see docs/architecture.md).")
    p.add_argument("--dataset", required=True, help="seqnet dataset directory (see docs/dataset_format.md)")
    p.add_argument("--method", "--methods", dest="methods", action="append", metavar="M[,M...]",
                   help="methods to run (repeatable or comma-separated; default: those of "
                        f"{', '.join(DEFAULT_METHODS)} the given models allow)")
    p.add_argument("--seq-len", type=positive_int, help="window length L (default: the S_L model's, else 5)")
    p.add_argument("--match-len", "--rerank-seq-len", dest="match_len", type=positive_int,
                   help="length L_m of SeqMatch and other sequence matchers (default: L; --rerank-seq-len: its "
                        "earlier name)")
    p.add_argument("--window", choices=WINDOW_MODES, help=f"window position (default {_D.window})")
    p.add_argument("--radius", type=positive_float, help="localisation radius (default: the dataset's)")
    p.add_argument("--extra-radius", type=positive_float, action="append", default=[],
                   help="also report at this radius")
    p.add_argument("--split", help="split to evaluate: train, val, test, all, or a range A:B (queries, the whole "
                   "reference) / A:B,C:D (reference, queries) (default: test when defined, else all)")
    add_resample_options(p)
    p.add_argument("--top-k", type=positive_int, help="HVPR shortlist size, of every HVPR method (default: each "
                   f"method's own, chosen on the val split when the dataset has one and another is evaluated, else "
                   f"{_D.top_k})")
    p.add_argument("--fuse-weight", type=non_negative_float,
                   help=f"hvpr-fused: weight λ of the S_L distance in its score (default {_D.fuse_weight:g})")
    p.add_argument("--fuse-top-k", type=positive_int, help=f"hvpr-fused: shortlist size (default {FUSED_TOP_K})")
    p.add_argument("--model", action="append", default=[], metavar="CKPT",
                   help="trained model checkpoint (S_L → 'seqnet', S_1 → 's1'); repeatable")
    p.add_argument("--shortlist-model", metavar="CKPT", help="S_L checkpoint used by 'seqnet' and HVPR shortlisting")
    p.add_argument("--rerank-model", metavar="CKPT",
                   help="S_1 checkpoint used by 's1', 's1+seqmatch' and HVPR re-ranking")
    p.add_argument("--backend", choices=list(KNN_BACKENDS), help=f"k-NN backend (default {_D.backend})")
    add_recall_options(p)
    add_calibration_options(p)
    p.add_argument("--confidence", choices=list(CONFIDENCES), help="what a top-1's confidence is (the per-query "
                   "confidence, the PR curve, --target-precision): ratio, from the query's own scores (the "
                   "localiser's); sequence, also whether the top-1s of the L queries on either side (the L before, "
                   "with causal windows) agree with it: far better at telling wrong answers on a route "
                   "(docs/online.md) (default ratio)")
    add_output_options(p)
    p.add_argument("--common-queries", action="store_true", help="evaluate every method on the sequence methods' "
                   "queries and references (one query set, as the paper's tables); by default single-frame methods "
                   "(single, s1) query and index every frame")
    add_allow_mismatch(p)
    add_device(p)
    p.set_defaults(func=run)


def add_output_options(p: argparse.ArgumentParser) -> None:
    """What eval reads besides descriptors (``--distances``, ``--index``) and what it writes (``--per-query``,
    ``--out``, ``--json``, ``--report``)."""
    p.add_argument("--per-query", metavar="FILE", help="per-query results: FILE.csv / .jsonl (per method and query: "
                   "the query's and top-5 references' rows in the dataset's names.txt, whatever the split, "
                   "their names, scores, correct or not, confidence); .txt: MSLS's predictions (one method; a "
                   "row per query key, then its top-20 reference keys: im2im image keys for single / s1, seq2seq "
                   "window keys for sequence methods; the log names evaluate.py's --task); no extension: a "
                   "VPR-methods-evaluation preds folder. "
                   "Named in --out DIR, it is written with the results, as one set")
    add_distances(p, "evaluated")
    p.add_argument("--index", metavar="MAP", help="evaluate the queries against this prebuilt map (seqnet index "
                   "build): its index shortlists, its frames re-rank; the reference side is not read")
    p.add_argument("--out", metavar="DIR", help="write results.json (results, resolved config, inputs) and "
                   "pr_curve.png (precision-recall of every method) here, as one set (a killed run leaves the old "
                   "set or the new one; your other files in DIR are kept)")
    p.add_argument("--json", metavar="FILE", help="also write the results JSON to FILE")
    p.add_argument("--overwrite", action="store_true", help="replace outputs (in --out DIR, --per-query, --json) "
                   "that seqnet did not write; by default they are refused before any work")
    p.add_argument("--report", action="store_true", help="also write a self-contained report.html to --out "
                   "(results, Recall@K and PR plots, distance matrix, example queries)")
    p.add_argument("--images-query", metavar="DIR|VIDEO", help="--report: folder of the query images, or the query "
                   "video of a dataset from-video (for the gallery and the worst / best pairs)")
    p.add_argument("--images-ref", metavar="DIR|VIDEO", help="--report: folder of the reference images, or the "
                   "reference video")


def add_recall_options(p: argparse.ArgumentParser) -> None:
    """``--ks`` and ``--recall-denominator``: which Recall@K, over which queries."""
    p.add_argument("--ks", type=int_list, metavar="K[,K...]",
                   help=f"the K of Recall@K (default {','.join(map(str, _D.ks))})")
    add_recall_denominator(p, _D.recall_denominator)


def run(args: argparse.Namespace) -> int:
    methods = parse_list(args.methods, None, "method") or None
    conf = EvalConfig().merge(methods=methods, seq_len=args.seq_len, match_len=args.match_len,
                                window=args.window, radius=args.radius, extra_radii=tuple(args.extra_radius) or None,
                                top_k=args.top_k, split=args.split, backend=args.backend, device=args.device,
                                ks=args.ks, allow_mismatch=args.allow_mismatch or None, fuse_weight=args.fuse_weight,
                                fuse_top_k=args.fuse_top_k, resample_every=args.resample_every,
                                resample_side=args.resample_side, recall_denominator=args.recall_denominator,
                                common_queries=args.common_queries, target_precision=args.target_precision,
                                calibrate_split=args.calibrate_split, risk=args.risk, confidence=args.confidence)
    check_calibration_options(args)
    check_distances(args)
    check_route(args)
    check_method_options(args, methods)
    report = report_config(args)
    outs = {"per_query": args.per_query, "figures": bool(args.out), "overwrite": args.overwrite, "json": args.json}
    if args.distances:
        from ..eval.matrix import main as matrix_main

        res = matrix_main(conf, args.dataset, args.distances, args.out, args.similarity, report=report,
                          transposed=args.transposed, **outs).data
    elif args.index:
        from ..maps import evaluate_main

        free = [k for k in ("top_k", "fuse_top_k", "fuse_weight") if getattr(args, k) is None]
        res = evaluate_main(conf, args.dataset, args.index, args.out, report=report, free=free, **outs).data
    else:
        from ..eval.select import main as choosing_main

        free = [k for k in ("top_k", "fuse_top_k", "fuse_weight") if getattr(args, k) is None]
        res = choosing_main(conf, args.dataset, args.out, args.model, args.shortlist_model, args.rerank_model,
                            free, report=report, **outs).data
    print_results(res)
    if report is not None:
        print(f"report: {shown(Path(args.out) / 'report.html')}")
    return 0


def print_results(res: dict) -> None:
    """The results table, what was evaluated and how many queries (names from the data shown escaped)."""
    cfg = res["config"]
    every = f", every {ordinal(cfg['resample_every'])} {cfg['resample_side']} frame" if cfg.get("resample_every") \
        else ""
    print(f"dataset {shown(cfg['dataset'])}, {ground_truth_text(cfg)}, L={cfg['seq_len']} ({cfg['window']}){every}")
    print(format_table(res["methods"], cfg["ks"]))
    print_extra_radii(res)
    fate = 'counted as failures' if cfg.get('recall_denominator') == 'all' else 'left out'
    counts: dict[tuple, list[str]] = {}  # methods evaluated on the same queries share a line
    for name, r in res["methods"].items():
        counts.setdefault((r["queries"], r["no_full_window"], r["no_positive"], r.get("no_full_window_reason"),
                           r.get("positive_not_indexed", 0)), []).append(name)
    lacking = "a positive" if cfg.get("ground_truth") == "explicit positives" else "a reference within the radius"
    for (queries, no_window, no_positive, why, unindexed), names in counts.items():
        who = "" if len(counts) == 1 else f"{', '.join(names)}: "
        print(f"{who}{counted(queries, 'query', 'queries')} evaluated; {no_window} without a full window"
              f"{f' ({why})' if why else ''}, {no_positive} without {lacking} ({fate})"
              + (f"; {unindexed} whose correct references all lie where no full window fits (a reference sequence "
                 "shorter than L, or its ends), counted as failures" if unindexed else ""))
    print_calibration(res)
    selection = res.get("selection", {})
    for line in [c["reason"] for c in selection.get("hvpr", [])] + [selection.get("not_chosen") or ""]:
        if line:
            print(shown(line))
    for name, r in res["methods"].items():
        for key in (k for k in r if k.startswith("shortlist_recall@")):
            print(f"{name}: {key} {r[key]:.3f} (the map's index against exact search)")
    for line in format_notes(learned_below_baseline(res)):
        print(shown(line))
    for key in ("trivial_ks", "few_queries"):
        if res.get(key):
            print(shown(f"note: {res[key]}"))
    alone = unmatched(res)
    if alone:
        print(shown(f"note: no model-free counterpart was evaluated for {'; '.join(alone)}"))


def print_extra_radii(res: dict) -> None:
    """Recall@K within each ``--extra-radius``, one line per method and radius."""
    explicit = res["config"].get("ground_truth") == "explicit positives"
    for radius in res["config"].get("extra_radii") or ():
        print(f"within {radius:g} of a positive (--extra-radius; the reference traverse's positions):" if explicit
              else f"within radius {radius:g} (--extra-radius):")
        for name, r in res["methods"].items():
            at = (r.get("radii") or {}).get(str(float(radius))) or (r.get("radii") or {}).get(str(radius)) or {}
            recalls = ", ".join(f"R@{k.split('@')[1]} {'-' if v is None else f'{v:.3f}'}" for k, v in at.items()
                                if k.startswith("recall@"))
            none = " (no query has a correct reference this near)" if at and at.get("queries") == 0 else ""
            print(f"  {shown(name)}: {recalls or '-'}{none}")


def print_calibration(res: dict) -> None:
    """Per method, the calibrated threshold and what it gives on the evaluated split (``--target-precision``)."""
    cfg = res["config"]
    if cfg.get("target_precision") is None:
        return
    print(f"calibrated on {shown(cfg['calibrate_split'])} for precision >= {cfg['target_precision']:g} "
          f"(risk {cfg['risk']:g}{', sequence confidence' if cfg.get('confidence') == 'sequence' else ''}); on "
          f"{shown(cfg.get('split') or 'the evaluated split')}:")
    for name, r in res["methods"].items():
        c = r.get("calibrated")
        if c is None:
            continue
        cal = c["calibration"]
        if cal["threshold"] is None:
            print(f"  {name}: abstains on every query ({cal['reason']})")
            continue
        print(f"  {name}: {calibrated_result(c)}")
    if any((r.get("calibrated") or {}).get("target_met") is False for r in res["methods"].values()):
        print(missed_target_note(shown(cfg["calibrate_split"]), cfg.get("calibrated_on_training_queries") is True))


def check_route(args: argparse.Namespace) -> None:
    """Options the route (--distances, --index, the dataset's descriptors) cannot apply are refused before work."""
    fixed = [f for f, v in (("--model", args.model), ("--shortlist-model", args.shortlist_model),
                            ("--rerank-model", args.rerank_model), ("--backend", args.backend)) if v]
    if args.distances and (fixed or args.index):
        raise ConfigError(f"--distances evaluates the given matrix; drop {'/'.join(fixed or ['--index'])} "
                          "(they apply to descriptors or a map)")
    if args.index and fixed:
        raise ConfigError("--index uses the map's models and index; drop --model/--shortlist-model/--rerank-model/"
                          "--backend (they are fixed when the map is built)")
    if args.target_precision is not None and (args.distances or args.index):
        raise ConfigError("--target-precision calibrates on another split of the dataset's descriptors; it is not "
                          "available with --distances or --index")


def report_config(args: argparse.Namespace) -> ReportConfig | None:
    """The report settings of ``--report`` (None without it); refuses report options without it."""
    if not args.report:
        if args.images_query or args.images_ref:
            raise ConfigError("--images-query / --images-ref are for the report: add --report")
        return None
    if not args.out:
        raise ConfigError("--report writes report.html beside results.json: give --out DIR")
    from ..report.html import ReportConfig  # the report's modules (figures, gallery) load only for --report
    from ..sources.video import is_video

    for flag, folder in (("--images-query", args.images_query), ("--images-ref", args.images_ref)):
        if folder is not None and not Path(folder).is_dir() and not (Path(folder).is_file() and is_video(folder)):
            raise ConfigError(f"{flag} {folder} is not a folder (nor a video file)")
    if bool(args.images_query) != bool(args.images_ref):
        raise ConfigError("the gallery needs both --images-query and --images-ref (or neither)")
    return ReportConfig(query_images=args.images_query,
                        ref_images=args.images_ref)
