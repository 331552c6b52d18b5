"""``seqnet dataset from-msls`` and the ``--positions-format`` options (RobotCar / KITTI logs) of
``from-csv`` and ``from-images``: the field's dataset layouts read as they ship (docs/interop.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..common import add_allow_mismatch, positive_float

POSITIONS_FORMATS = ("csv", "robotcar-ins", "kitti-oxts")  # seqnet.data.gps.POSITIONS_FORMATS (checked by a test)


def add_positions_format(p: argparse.ArgumentParser) -> None:
    """``--positions-format`` and ``--max-time-gap``: how the --ref-csv / --query-csv files are read."""
    p.add_argument("--positions-format", choices=POSITIONS_FORMATS, default="csv",
                   help="what --ref-csv / --query-csv are: csv (a positions CSV, default), robotcar-ins (Oxford "
                        "RobotCar gps/ins.csv or gps.csv; images named <timestamp us>.png), kitti-oxts (a KITTI "
                        "drive's oxts/ folder; image times from image_0x/timestamps.txt); an image takes the "
                        "position of the nearest sample in time")
    p.add_argument("--max-time-gap", type=positive_float, metavar="SECONDS",
                   help="refuse an image farther than this from every position sample (default 0.1 s)")


def register_from_msls(dsub: argparse._SubParsersAction, finish) -> None:  # noqa: ANN001 - a function
    p = dsub.add_parser(
        "from-msls", help="from Mapillary SLS city folders (postprocessed.csv + seq_info.csv) and descriptors",
        description="Read MSLS as it ships: ROOT/train_val/<city>/database|query/ with postprocessed.csv "
                    "(easting, northing), seq_info.csv (sequence_key, frame_number: order and sequence bounds) "
                    "and images/. Database = reference, query = query; descriptors matched to images by key "
                    "(names from HDF5, --*-names, or the images/ folder in sorted order). One split per city, "
                    "named by its role in the paper (train melbourne, val austin, test amman / boston / sf / "
                    "copenhagen), radius and training radii from the msls preset.")
    p.add_argument("root", metavar="ROOT", help="MSLS root (holding train_val/), or one city's folder")
    p.add_argument("--city", action="append", required=True, metavar="CITY",
                   help="MSLS city (folder name; copenhagen = cph, san-francisco = sf), or paper-train / "
                        "paper-val / paper-test for the paper's cities; repeatable")
    for side in ("ref", "query"):
        what = "database" if side == "ref" else "query"
        p.add_argument(f"--{side}-desc", action="append", required=True, metavar="FILE",
                       help=f"descriptors of the {what} images (.npy, .h5): one for all cities or one per --city")
        p.add_argument(f"--{side}-names", action="append", metavar="FILE|DIR",
                       help=f"names of the {what} descriptors (file, or image folder); default: HDF5 names, "
                            "else the city's images/ folder")
    p.add_argument("--out", required=True, metavar="DIR", help="output dataset directory")
    p.add_argument("--radius", type=positive_float, help="localisation radius in metres (default: msls preset, 20)")
    p.add_argument("--pos-radius", type=positive_float, help="training positive radius (default: msls preset)")
    p.add_argument("--neg-radius", type=positive_float, help="training negative radius (default: msls preset)")
    p.add_argument("--name", help="dataset name (default: msls-<cities>)")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if seqnet wrote it")
    add_allow_mismatch(p)
    p.set_defaults(func=lambda args: run_from_msls(args, finish))


def run_from_msls(args: argparse.Namespace, finish) -> int:  # noqa: ANN001 - a function
    from ...data.msls import dataset_from_msls

    extra = {k: v for k, v in (("pos_radius", args.pos_radius), ("neg_radius", args.neg_radius)) if v}
    ds = dataset_from_msls(args.root, args.city, args.ref_desc, args.query_desc, args.ref_names, args.query_names,
                           args.radius, args.name or Path(args.out).name, extra, args.allow_mismatch)
    return finish(ds, args)
