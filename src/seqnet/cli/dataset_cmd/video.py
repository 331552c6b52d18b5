"""``seqnet dataset from-video``: two videos (+ GPS tracks, or frame-aligned) → a dataset, described consistently."""

from __future__ import annotations

import argparse
import json

from ...describe import DESCRIBERS
from ...pipelines.from_video import FIT_ON, FromVideoConfig, main
from ..common import add_device, positive_float
from ..describe_cmd import add_describe_options, describe_config
from .images import written
from .splits import parse_splits


def add_video_options(p: argparse.ArgumentParser) -> None:
    """--fps and --video-start: how a video's frames are sampled and placed in time."""
    p.add_argument("--fps", type=positive_float, metavar="F", help="frames kept per second of video time (default: "
                   "every frame)")
    p.add_argument("--video-start", metavar="ISO", help="when the video's first frame was recorded (ISO-8601, "
                   "e.g. 2024-05-01T10:00:00Z), overriding its creation_time: joins tracks of absolute times; with "
                   "two videos, query=ISO and/or reference=ISO (comma-separated) sets one video's, ISO both")


def register_from_video(dsub: argparse._SubParsersAction) -> None:
    p = dsub.add_parser(
        "from-video", help="describe two videos with one describer and build the dataset (GPS tracks or aligned)",
        description="Read the reference and query videos frame by frame (PyAV), name each frame by its video time, "
                    "place it by a positions file (GPX, NMEA 0183 RMC/GGA, or CSV with a time column: "
                    "--ref-positions / --query-positions; frames outside the track are dropped and counted) or by "
                    "frame order (--aligned), keep --fps frames per second or one every --every-metres, describe "
                    "both with ONE describer and build a seqnet dataset. See docs/video.md.")
    p.add_argument("reference", metavar="REF_VIDEO", help="reference video file")
    p.add_argument("query", metavar="QUERY_VIDEO", help="query video file")
    p.add_argument("--method", required=True, choices=list(DESCRIBERS), help="descriptor method")
    p.add_argument("--out", required=True, metavar="DIR", help="output dataset directory")
    add_video_options(p)
    p.add_argument("--every-metres", type=positive_float, metavar="M", help="keep one frame per M metres travelled "
                   "(needs positions; instead of --fps)")
    p.add_argument("--ref-positions", metavar="FILE", help="reference track: GPX, NMEA or CSV (time + lat, lon "
                   "or x, y)")
    p.add_argument("--query-positions", metavar="FILE", help="query track (with --ref-positions)")
    p.add_argument("--aligned", action="store_true", help="no positions: query frame i shows the place of reference "
                   "frame i (radius in frames)")
    p.add_argument("--radius", type=positive_float, help="localisation radius, inclusive (metres with positions, "
                   "frames with --aligned; default 25 m, or 1 frame)")
    p.add_argument("--max-gap", type=positive_float, metavar="SECONDS", help="track samples further apart than this "
                   "place no frame between them (default 10 s)")
    for side, what in (("ref", "reference"), ("query", "query")):
        p.add_argument(f"--{side}-stream", type=int, metavar="N", help=f"the {what} file's video stream N (0: its "
                       "first; default: the first that is not a cover picture, warned when it holds several)")
    p.add_argument("--split", action="append", default=[], metavar="NAME=A:B[,C:D]",
                   help="named split of the kept frames: NAME=A:B selects query frames A:B against the whole "
                   "reference; NAME=A:B,C:D gives the reference range A:B and the query frames C:D; repeatable")
    p.add_argument("--fit-on", choices=FIT_ON, default="reference", help="frames to fit PCA / NetVLAD clusters on")
    p.add_argument("--name", help="dataset name (default: the output directory name)")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if seqnet wrote it")
    add_describe_options(p, fit=False)
    add_device(p)
    p.set_defaults(func=run_from_video)


def run_from_video(args: argparse.Namespace) -> int:
    radius = args.radius or (1.0 if args.aligned else 25.0)
    conf = FromVideoConfig(describe=describe_config(args), fps=args.fps, every_metres=args.every_metres,
                           aligned=args.aligned, radius=radius, video_start=args.video_start, fit_on=args.fit_on,
                           name=args.name, streams=(args.ref_stream, args.query_stream),
                           splits=parse_splits(args.split),
                           **({"max_gap": args.max_gap} if args.max_gap else {}))
    out = main(conf, args.reference, args.query, args.out, (args.ref_positions, args.query_positions),
               overwrite=args.overwrite)
    meta = json.loads((out / "dataset.json").read_text(encoding="utf-8"))
    videos = meta.get("videos", {})
    counts = "; ".join(f"{side}: {v['frames']['kept']} of {v['frames']['total']} frames kept"
                       + (f", {v['frames']['outside']} outside its track" if v["frames"]["outside"] else "")
                       for side, v in videos.items())
    print(f"{written(out, meta)}: radius {meta['radius']:g} {meta['position_unit']}, descriptors "
          f"{meta['provenance']['reference']['settings']['method']} D={meta['provenance']['reference']['dim']}; "
          f"{counts}")
    print(f"next: seqnet eval --dataset {out}")
    return 0
