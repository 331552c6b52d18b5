"""``seqnet dataset ...``: build datasets from CSV / UTM-named / seqNet files, check them, list presets."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ...core.errors import ConfigError
from .. import COMMANDS
from ..common import add_allow_mismatch, positive_float
from .splits import parse_splits

PRESET_HELP = ("dataset preset (nordland, alias nordland-sw / nordland-sf; oxford-v1.0, oxford-pnv, brisbane, msls): "
               "radius, training radii, splits")


def register(sub: argparse._SubParsersAction) -> None:
    from .foreign import register_from_msls  # the sub-commands' modules load only for `seqnet dataset`
    from .images import register_from_images  # (eval imports .resample: not describe's modules with it)
    from .resample import register_resample
    from .video import register_from_video

    p = sub.add_parser("dataset", help=COMMANDS["dataset"],
                       description="Build datasets in the seqnet directory format and check them (docs/datasets.md).")
    dsub = p.add_subparsers(dest="dataset_command", metavar="SUBCOMMAND", required=True)
    _register_csv(dsub)
    _register_utm(dsub)
    _register_seqnet(dsub)
    register_from_images(dsub, parse_splits)
    register_from_video(dsub)
    register_from_msls(dsub, finish)
    register_resample(dsub)
    c = dsub.add_parser("check", help="validate a dataset directory and print a summary")
    c.add_argument("dir", metavar="DIR", help="seqnet dataset directory")
    c.add_argument("--json", action="store_true", help="print the summary as JSON")
    c.set_defaults(func=run_check)
    ps = dsub.add_parser("presets", help="list the dataset presets")
    ps.add_argument("--json", action="store_true", help="print the presets as JSON")
    ps.set_defaults(func=run_presets)
    for name, leaf in dsub.choices.items():  # errors name the subcommand: "seqnet dataset from-images: error: ..."
        leaf.set_defaults(command=f"dataset {name}")


def _common(p: argparse.ArgumentParser, radius: bool = True) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="output dataset directory")
    p.add_argument("--preset", help=PRESET_HELP)
    if radius:
        p.add_argument("--radius", type=positive_float, help="localisation radius (metres or frames; default: preset)")
    p.add_argument("--pos-radius", type=positive_float, help="training positive radius (stored as metadata)")
    p.add_argument("--neg-radius", type=positive_float, help="training negative radius (stored as metadata)")
    p.add_argument("--split", action="append", default=[], metavar="NAME=A:B[,C:D]",
                   help="named split: NAME=A:B selects queries A:B against the whole reference; NAME=A:B,C:D "
                   "gives the reference range A:B and the queries C:D; repeatable")
    p.add_argument("--name", help="dataset name (default: the output directory name)")
    p.add_argument("--positives", metavar="FILE", help="explicit ground truth: per query the matching reference "
                   "indices (.json list of lists, .csv query,reference pairs, or .npy object array); used "
                   "instead of the radius")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    add_allow_mismatch(p)


def _register_csv(dsub: argparse._SubParsersAction) -> None:
    from .foreign import add_positions_format

    p = dsub.add_parser("from-csv", help="from position CSVs (name + easting,northing or frame) and descriptor files",
                        description="CSV header: an image column (name/image/filename/...) and easting,northing "
                                    "(metres), lat,lon (degrees: UTM metres, the query in the reference's zone) or "
                                    "frame; optional sequence column. Rows are matched to descriptors by image name "
                                    "(HDF5 'names' or --*-names file), else taken in order.")
    for side in ("ref", "query"):
        p.add_argument(f"--{side}-csv", required=True, help=f"{side} positions CSV")
        p.add_argument(f"--{side}-desc", required=True, help=f"{side} descriptors (.npy, .h5, .hdf5)")
        p.add_argument(f"--{side}-names", help=f"names of the {side} descriptors (one per line, for .npy)")
    add_positions_format(p)
    _common(p)
    p.set_defaults(func=run_from_csv)


def _register_utm(dsub: argparse._SubParsersAction) -> None:
    p = dsub.add_parser("from-utm-names", help="from descriptor files whose image names carry @easting@northing@",
                        description="Positions are parsed from image names like '@0543256.96@4477929.94@17@T@...jpg' "
                                    "(Pittsburgh, Tokyo 24/7, MSLS-style).")
    for side in ("ref", "query"):
        p.add_argument(f"--{side}-desc", required=True, help=f"{side} descriptors (.npy, .h5, .hdf5)")
        p.add_argument(f"--{side}-names", help=f"{side} image names, one per line, or an image folder in "
                       "VPR-methods-evaluation's order: the lines of DIR_images_paths.txt beside it, else its "
                       ".jpg/.jpeg/.png files, sorted(glob('**/*')) (default: HDF5 'names')")
        p.add_argument(f"--{side}-seq-bounds", help=f"{side} sequence bounds file ('start end' per image)")
    _common(p)
    p.set_defaults(func=run_from_utm)


def _register_seqnet(dsub: argparse._SubParsersAction) -> None:
    p = dsub.add_parser("from-seqnet", help="from the original seqNet .db struct files and descriptor .npy files",
                        description="One split per --db (its whichSet). Descriptors: one file for all --db, or one "
                                    "per --db; for Nordland the whole clean-list array works too (indexed by frame). "
                                    "Without --db, --preset nordland builds the whole frame list with the paper's "
                                    "index splits.")
    p.add_argument("--db", action="append", default=[], metavar="FILE.db", help="seqNet struct file; repeatable")
    p.add_argument("--ref-desc", action="append", required=True, metavar="R.npy", help="reference descriptors")
    p.add_argument("--query-desc", action="append", required=True, metavar="Q.npy", help="query descriptors")
    p.add_argument("--ref-seq-bounds", action="append", metavar="FILE", help="MSLS reference seqBounds, one per --db")
    p.add_argument("--query-seq-bounds", action="append", metavar="FILE", help="MSLS query seqBounds, one per --db")
    p.add_argument("--names", help="frame-list image names (without --db), e.g. nordland_clean_imageNames.txt")
    p.add_argument("--radius", type=positive_float, help="localisation radius (default: preset, else the struct)")
    p.add_argument("--name", help="dataset name")
    p.add_argument("--out", required=True, metavar="DIR", help="output dataset directory")
    p.add_argument("--preset", help=PRESET_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    add_allow_mismatch(p)
    p.set_defaults(func=run_from_seqnet)


def finish(ds, args: argparse.Namespace) -> int:  # noqa: ANN001
    from ...core.provenance import described_text
    from ...data.io import save_dataset
    from ...data.sanity import review
    from ...metrics.summary import summarize_dataset
    from ...pipelines.ground_truth import check_true_matches

    check_true_matches(ds)  # no query with a true match: refused, nothing written; few: one warning line
    save_dataset(ds, args.out, overwrite=args.overwrite, quiet=True)  # said below, with more
    review(ds)  # likely mistakes (the same images, splits sharing queries, constant positions): one line each
    s = summarize_dataset(ds)
    dim, text = f"D={s['reference']['dim']}", described_text(ds.reference.provenance)  # method, views beside D
    print(f"wrote {args.out}: reference {s['reference']['images']} and query {s['query']['images']} images, "
          f"{dim if text in ('', dim) else 'descriptors ' + text}, radius {ds.radius:g} {ds.position_unit}, "
          f"{s['queries_with_match']} queries with a true match, splits: {', '.join(ds.splits) or 'none'}")
    return 0


def _positives(args: argparse.Namespace):  # noqa: ANN202
    from ...data.positives import read_positives

    return read_positives(args.positives) if args.positives else None


def _extra(args: argparse.Namespace) -> dict:
    return {"pos_radius": args.pos_radius, "neg_radius": args.neg_radius}


def run_from_csv(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ...data.convert import assemble_dataset, traverse_from_csv, traverses_in_metres
    from ...data.gps import DEFAULT_MAX_GAP, ZONE_HINT, check_zones, traverse_from_log

    extra = _extra(args)
    if args.positions_format != "csv":
        gap = args.max_time_gap or DEFAULT_MAX_GAP
        ref, unit_r, zone_r = traverse_from_log(args.positions_format, args.ref_csv, args.ref_desc, args.ref_names,
                                                "reference", gap)
        qry, unit_q, zone_q = traverse_from_log(args.positions_format, args.query_csv, args.query_desc,
                                                args.query_names, "query", gap)
        if unit_r == unit_q == "metres":  # logged easting/northing; lat/lon: below, as a CSV's
            check_zones(zone_r, zone_q, ZONE_HINT)
            zone = zone_q if zone_r == "?" else zone_r
            extra["positions_frame"] = f"UTM zone {zone}"  # localize --positions-topic checks its positions against it
    else:
        from ...data.convert.swapped import told_swapped

        with told_swapped("reference", args.query_desc):
            ref, unit_r = traverse_from_csv(args.ref_csv, args.ref_desc, args.ref_names, "reference")
        with told_swapped("query", args.ref_desc):
            qry, unit_q = traverse_from_csv(args.query_csv, args.query_desc, args.query_names, "query")
    if unit_r != unit_q:
        from ...data.utm import mixed_frames

        raise ConfigError(mixed_frames(unit_r, unit_q, "CSVs" if args.positions_format == "csv" else "logs"))
    if unit_r == "degrees":  # lat/lon columns: UTM metres, the query in the reference's zone
        ref, qry, extra["positions_frame"] = traverses_in_metres(ref, qry, (args.ref_csv, args.query_csv))
        unit_r = "metres"
    ds = assemble_dataset(ref, qry, unit_r, args.radius, args.preset, parse_splits(args.split),
                          args.name or Path(args.out).name, extra, _positives(args), args.allow_mismatch)
    return finish(ds, args)


def run_from_utm(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    from ...data.convert import assemble_dataset, read_seq_bounds, traverse_from_utm_names
    from ...data.convert.swapped import told_swapped

    sides = []
    for side, label in (("ref", "reference"), ("query", "query")):
        with told_swapped(label, getattr(args, f"{'query' if side == 'ref' else 'ref'}_desc")):
            t = traverse_from_utm_names(getattr(args, f"{side}_desc"), getattr(args, f"{side}_names"), label)
        bounds = getattr(args, f"{side}_seq_bounds")
        if bounds:
            t = dataclasses.replace(t, seq_bounds=read_seq_bounds(bounds, len(t)))
        sides.append(t)
    ds = assemble_dataset(sides[0], sides[1], "metres", args.radius, args.preset, parse_splits(args.split),
                          args.name or Path(args.out).name, _extra(args), _positives(args),
                          args.allow_mismatch)
    return finish(ds, args)


def run_from_seqnet(args: argparse.Namespace) -> int:
    from ...data.readers import read_descriptor_file, read_names
    from ...data.structfiles import dataset_from_frame_lists, dataset_from_structs, read_db_struct

    ref = [read_descriptor_file(f)[0] for f in args.ref_desc]
    qry = [read_descriptor_file(f)[0] for f in args.query_desc]
    if not args.db:
        if not args.preset or len(ref) != 1 or len(qry) != 1:
            raise ConfigError("without --db, give --preset nordland and one --ref-desc and --query-desc "
                              "(descriptors of the whole frame list)")
        names = read_names(args.names) if args.names else None
        ds = dataset_from_frame_lists(ref[0], qry[0], args.preset, names, args.name)
    else:
        structs = [read_db_struct(f) for f in args.db]
        ds = dataset_from_structs(structs, ref, qry, args.preset, args.ref_seq_bounds, args.query_seq_bounds,
                                  args.radius, args.name)
    ds.reference.provenance, ds.query.provenance = _same_provenance(args.ref_desc, args.query_desc,
                                                                    args.allow_mismatch)
    return finish(ds, args)


def _same_provenance(ref_files: list[str], query_files: list[str], allow: bool) -> tuple[dict | None, dict | None]:
    """The provenance of the reference and query descriptor files, checked to be one (unless ``allow``)."""
    from ...core.provenance import check_same
    from ...data.readers import read_provenance

    records = [read_provenance(f) for f in (*ref_files, *query_files)]
    for f, rec in zip((*ref_files, *query_files), records, strict=True):
        check_same(records[0], rec, f"the descriptors of {ref_files[0]}", f"the descriptors of {f}", allow)
    return records[0], records[len(ref_files)]


def run_check(args: argparse.Namespace) -> int:
    from ...core.errors import DatasetError
    from ...core.log import logger
    from ...data.io import load_dataset, recorded_digests
    from ...data.order import frame_order_lines
    from ...data.sanity import review
    from ...metrics.summary import summarize_dataset
    from ...pipelines.ground_truth import mismatch_hint
    from ...security.digests import changed_files
    from ...security.text import shown

    ds = load_dataset(args.dir)
    changed = changed_files(Path(args.dir), recorded_digests(args.dir), full=True)
    if changed:
        raise DatasetError(f"{args.dir}: {', '.join(changed)} changed since seqnet wrote the dataset (every byte "
                           "hashed); hint: write it again, or drop 'checksums' from dataset.json if you changed "
                           "its files on purpose")
    review(ds)  # frame-aligned traverses that do not pair up: refused; likely mistakes: one warning line each
    for line in frame_order_lines(ds):  # names listed in text order: nothing else shows it with frame-index truth
        logger.warning("%s: %s", ds.name, shown(line))
    s = summarize_dataset(ds)
    if args.json:
        print(json.dumps(s, indent=2, default=str))
    else:
        print(format_summary(s))
    if s["queries_with_match"] == 0:
        what = "an explicit positive" if ds.positives is not None else \
            f"a reference within radius {ds.radius:g} {ds.position_unit}"
        raise DatasetError(f"{args.dir}: no query has {what}: {mismatch_hint(ds, 0)}")
    return 0


def format_summary(s: dict) -> str:
    """Human-readable lines of a :func:`seqnet.metrics.summary.summarize_dataset` summary."""
    lines = [f"dataset {s['name']}: radius {s['radius']:g} {s['position_unit']}; ground truth: {s['ground_truth']}"]
    for side in ("reference", "query"):
        t = s[side]
        seq = t.get("sequences")
        seq_txt = ", no sequence bounds"
        if seq:
            seq_txt = (f", {seq['count']} sequences (length {seq['min_len']}..{seq['max_len']}, "
                       f"median {seq['median_len']:g})")
        lines.append(f"  {side}: {t['images']} images, D={t['dim']}{seq_txt}")
    lines.append(f"  queries with a true match: {s['queries_with_match']} of {s['query']['images']}")
    for name, sp in s["splits"].items():
        lines.append(f"  split {name}: reference {sp['reference'][0]}:{sp['reference'][1]}, query "
                     f"{sp['query'][0]}:{sp['query'][1]}, {sp['queries_with_match']} queries with a match")
    if s["metadata"]:  # one line per key; a nested value (provenance, source) shortened to its first 100 characters
        lines.append("  metadata:")
        for key, value in s["metadata"].items():
            text = value if isinstance(value, str) else json.dumps(value, default=str)
            lines.append(f"    {key}: {text if len(text) <= 100 else text[:97] + '...'}")
    return "\n".join(lines)


def run_presets(args: argparse.Namespace) -> int:
    from ...data.presets import PRESETS, preset_summary

    if args.json:
        print(json.dumps(PRESETS, indent=2))
        return 0
    for name in PRESETS:
        print(preset_summary(name))
    return 0
