"""``seqnet dataset from-images``: two image folders + ground truth → a dataset, described consistently."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ...core.provenance import described_text
from ...describe import DESCRIBERS
from ...pipelines.descriptor_choice import CANDIDATES
from ...pipelines.from_images import FIT_ON, FromImagesConfig, main
from ...sources.bags.positions import DEFAULT_TOLERANCE
from ..common import add_device, add_topic, positive_float, positive_int
from ..describe_cmd import add_describe_options, describe_config
from .foreign import add_positions_format


def register_from_images(dsub: argparse._SubParsersAction, parse_splits) -> None:  # noqa: ANN001 - a function
    p = dsub.add_parser(
        "from-images", help="describe two image folders with one describer and build the dataset",
        description="Describe the reference and query image folders (or list files) with ONE describer (same "
                    "settings, one fit of PCA / NetVLAD clusters), so their descriptors are comparable, and build "
                    "a dataset with the ground truth given: positions CSVs (--ref-csv/--query-csv), UTM-coded "
                    "image names (--utm-names), frame-aligned traverses (--frame-aligned, radius in frames), or "
                    "explicit positives (--positives FILE), or a positions topic of two ROS bags (--topic, "
                    "--positions-topic). See docs/own_data.md and docs/online.md (ROS bags).")
    p.add_argument("reference", metavar="REF_IMAGES", help="reference image folder, list file or ROS bag")
    p.add_argument("query", metavar="QUERY_IMAGES", help="query image folder, list file or ROS bag")
    p.add_argument("--method", choices=list(DESCRIBERS), help=f"descriptor method (default: chosen on the val "
                   f"split, which must be given, among {', '.join(CANDIDATES)} (installed weights only; netvlad+"
                   "equalize: NetVLAD of the raw and the histogram-equalised images, --views) by raw+seqmatch R@1)")
    p.add_argument("--out", required=True, metavar="DIR", help="output dataset directory")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--ref-csv", metavar="FILE", help="reference positions CSV (image name + easting,northing, "
                   "lat,lon (degrees: UTM metres) or frame; optional sequence); needs --query-csv")
    g.add_argument("--utm-names", action="store_true", help="positions from '@easting@northing@' in image names")
    g.add_argument("--frame-aligned", action="store_true",
                   help="query frame i shows the place of reference frame i (radius in frames)")
    g.add_argument("--positives", metavar="FILE", help="explicit positives: per query the matching reference "
                   "indices (.json list of lists, .csv query,reference pairs, .npy object array)")
    g.add_argument("--positions-topic", metavar="TOPIC", help="both traverses are ROS bags: positions from this topic "
                   "of each (sensor_msgs/NavSatFix: UTM metres; nav_msgs/Odometry, geometry_msgs/PoseStamped: x, y), "
                   "matched to each image by the nearest timestamp")
    p.add_argument("--positions-tolerance", type=positive_float, metavar="SECONDS", help="with --positions-topic: "
                   f"the largest gap between an image and its position message (default {DEFAULT_TOLERANCE:g} s)")
    add_topic(p, "REF_IMAGES / QUERY_IMAGES")
    p.add_argument("--query-csv", metavar="FILE", help="query positions CSV (with --ref-csv)")
    add_positions_format(p)
    p.add_argument("--radius", type=positive_float,
                   help="localisation radius, inclusive (metres for CSV eastings / UTM names, else frames); "
                   "required except with --positives, whose spread implies one")
    p.add_argument("--fit-on", default="reference", metavar=f"{'|'.join(FIT_ON)}|SPLIT",
                   help="images to fit PCA / NetVLAD clusters on: the reference (default), both traverses, or "
                        "a split given with --split")
    p.add_argument("--split", action="append", default=[], metavar="NAME=A:B[,C:D]",
                   help="named split: NAME=A:B selects queries A:B against the whole reference; NAME=A:B,C:D "
                   "gives the reference range A:B and the queries C:D; repeatable")
    p.add_argument("--name", help="dataset name (default: the output directory name)")
    p.add_argument("--pos-radius", type=positive_float, help="training positive radius (stored as metadata)")
    p.add_argument("--neg-radius", type=positive_float, help="training negative radius (stored as metadata)")
    p.add_argument("--pca", type=positive_int, metavar="D", help="reduce the descriptors to D dimensions by a PCA "
                   "fitted on the train split only (needs --split train=...; saved as DIR.pca.npz; its cost in "
                   "model-free val R@1 is measured and said: seqnet train advises one only where it keeps them)")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if seqnet wrote it")
    add_describe_options(p, fit=False)
    add_device(p)
    p.set_defaults(func=lambda args: run_from_images(args, parse_splits))


def run_from_images(args: argparse.Namespace, parse_splits) -> int:  # noqa: ANN001 - a function
    truth = ("csv" if args.ref_csv else "utm" if args.utm_names else "frames" if args.frame_aligned
             else "bag" if args.positions_topic else "positives")
    from ...core.errors import ConfigError

    if args.positions_format != "csv" and truth != "csv":
        raise ConfigError(f"--positions-format {args.positions_format} reads --ref-csv / --query-csv (the logs)")
    if truth == "csv" and not args.query_csv:
        raise ConfigError("--ref-csv needs --query-csv (the query positions)")
    if args.radius is None and truth != "positives":
        raise ConfigError(f"--radius is required with {truth} ground truth (metres or frames; only --positives "
                          "implies one)")
    choose = args.method is None
    if choose and getattr(args, "describer", None):
        raise ConfigError("--describer needs --method plugin (without --method the descriptor is chosen on the val "
                          f"split among {', '.join(CANDIDATES)})")
    if choose and getattr(args, "views", None):
        raise ConfigError(f"--views goes with --method (without --method the descriptor is chosen on the val split "
                          f"among {', '.join(CANDIDATES)}: netvlad+equalize is NetVLAD with --views raw,equalize); "
                          f"hint: --method netvlad --views {args.views}")
    if choose:
        args.method = "pixels"  # the candidates take the other describe options; pixels: a valid placeholder
    conf = FromImagesConfig(describe=describe_config(args), fit_on=args.fit_on, ground_truth=truth,
                            radius=args.radius, splits=parse_splits(args.split), name=args.name,
                            pos_radius=args.pos_radius, neg_radius=args.neg_radius,
                            positions_format=args.positions_format,
                            positions_tolerance=args.positions_tolerance or DEFAULT_TOLERANCE, pca=args.pca,
                            candidates=CANDIDATES if choose else (),
                            **({"max_time_gap": args.max_time_gap} if args.max_time_gap else {}))
    out = main(conf, args.reference, args.query, args.out,
               positions=(args.ref_csv, args.query_csv) if truth == "csv" else None,
               positives=args.positives, overwrite=args.overwrite, topic=args.topic,
               positions_topic=args.positions_topic)
    meta = json.loads((out / "dataset.json").read_text(encoding="utf-8"))
    label = args.positions_format if truth == "csv" and args.positions_format != "csv" else truth
    print(f"{written(out, meta)}: ground truth {label}, radius {meta['radius']:g} {meta['position_unit']}, "
          f"descriptors {described_text(meta['provenance']['reference'])} "
          f"(provenance {meta['provenance']['reference']['id']})")
    if meta.get("pca"):
        print(pca_line(meta["pca"]))
    print(f"next: seqnet eval --dataset {out}")
    return 0


def written(out: Path, meta: dict) -> str:
    """``wrote dataset OUT (reference N, query M images)``, and its name when it is not the directory's."""
    from ...data.io import load_descriptors

    ref, qry = (len(load_descriptors(out / side)[0]) for side in ("reference", "query"))  # memory-mapped: the shape
    named = "" if meta.get("name") == out.name else f", named {meta.get('name')!r}"
    return f"wrote dataset {out} (reference {ref}, query {qry} images{named})"


def pca_line(pca: dict) -> str:
    """``PCA 2048 -> 256 fitted on the train split only: FILE``, and what it costs when it loses val queries (its
    recorded ``cost``: :func:`seqnet.pipelines.pca.cost_record`)."""
    cost = pca.get("cost") or {}
    lost = ("; it lowers " + ", ".join(f"{m} {cost['split']} R@1 {cost['before'][m]:.3f} -> {cost['after'][m]:.3f}"
                                       for m in cost["before"]) + " (warned above)") if cost.get("lost") else ""
    return f"PCA {pca['input_dim']} -> {pca['dims']} fitted on the {pca['fit_split']} split only: {pca['file']}{lost}"
