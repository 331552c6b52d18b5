"""``seqnet localize``: localise a query stream frame by frame (online, causal windows): a dataset's
query traverse replayed (``--dataset``), or new descriptors or images against a map (``--map --query``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import ConfigError
from ..core.stage import Written
from ..eval.select import SELECTABLE
from ..localize.config import TOP_K, LocalizeConfig, map_settings
from ..localize.replay import main
from ..localize.stream import Query, stream
from ..localize.trackfile import TRACK_COLUMNS
from ..localize.video import VideoOptions
from ..matching.velocity import ANCHORS
from ..methods.grammar import valid_methods
from ..metrics.calibration import RISK, check_target
from ..search.precision import PRECISIONS
from ..security.text import shown
from ..sources.bags.positions import DEFAULT_TOLERANCE
from . import COMMANDS
from .common import (
    add_allow_mismatch,
    add_calibration_options,
    add_device,
    add_distances,
    add_topic,
    calibrated_result,
    check_calibration_options,
    check_distances,
    check_method_options,
    missed_target_note,
    positive_float,
    positive_int,
)

_D = LocalizeConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help=COMMANDS["localize"],
                       description="Replay the query traverse of a dataset (--dataset), or stream query "
                       "descriptors or images against a map (--map, --query), frame by frame through the online "
                       "localiser (causal windows, one answer per frame) and write one CSV row per frame: "
                       + ", ".join(TRACK_COLUMNS) + ". Methods: " + ", ".join(valid_methods())
                       + ", or hvpr-<shortlister>:<frames>+<matcher> (not grh, grh-dh). See docs/online.md.")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--dataset", help="seqnet dataset directory: replay its query traverse against its reference")
    src.add_argument("--map", help="the map: an index map (seqnet index build --window causal; its index "
                     "shortlists) or a seqnet dataset directory, whose reference traverse is used")
    p.add_argument("--query", metavar="DESCRIPTORS|IMAGES|BAG|VIDEO|URL", help="with --map: a descriptor file (.npy, "
                   ".h5), a folder / list file of images, a ROS bag (with --topic), a video file, or a live stream (a "
                   "URL or /dev/videoN), described one by one as the map was (see docs/online.md, docs/video.md)")
    add_video_query(p)
    p.add_argument("--resize", metavar="WxH", help="with --map and query images (a folder, list file, bag or video): "
                   "describe them at WxH, the size of the map's reference images, when the map was described at "
                   "the images' own size (pixels' default) and the query images are another size")
    add_topic(p, "--query")
    p.add_argument("--positions-topic", metavar="TOPIC", help="with a ROS bag as --query: the ground truth, each frame "
                   "at the position of this topic's message nearest in time (sensor_msgs/NavSatFix: UTM metres; "
                   "nav_msgs/Odometry, geometry_msgs/PoseStamped: x, y), in the frame the map records; the track gets "
                   "its 'correct' column and the summary R@1, AUC, R@100P")
    p.add_argument("--positions-tolerance", type=positive_float, metavar="SECONDS", help="with --positions-topic: the "
                   f"largest gap between a frame and its position message (default {DEFAULT_TOLERANCE:g} s)")
    add_distances(p, "with --dataset: streamed row by row")
    p.add_argument("--out", required=True, metavar="TRACK.csv",
                   help="the per-frame CSV; a summary (config, inputs, R@1, latency) goes beside it as .json")
    add_localizer_options(p)
    add_calibration_options(p)
    p.set_defaults(func=run, default_threads=1)  # a frame is little work: one thread (docs/online.md)


def add_localizer_options(p: argparse.ArgumentParser) -> None:
    """The localiser's options (method, describer, models, L, L_m, K, k, anchor, split, radius, precision,
    --allow-mismatch, --device): ``seqnet localize`` and ``seqnet serve`` share them, names and defaults."""
    p.add_argument("--method", help=f"method (default: an index map's own, the one seqnet index build made it for; "
                   f"else {_D.method})")
    p.add_argument("--describer", metavar="PKG.MODULE:FACTORY", help="with --map and query images: the plug-in "
                   "describer the map was made with, named here because seqnet imports no code a file names")
    p.add_argument("--model", action="append", default=[], metavar="CKPT",
                   help="trained model checkpoint (S_L → 'seqnet', S_1 → 's1'); repeatable")
    p.add_argument("--shortlist-model", metavar="CKPT", help="S_L checkpoint (seqnet, HVPR shortlists)")
    p.add_argument("--rerank-model", metavar="CKPT", help="S_1 checkpoint (s1, s1+<matcher>, HVPR re-ranking)")
    p.add_argument("--seq-len", type=positive_int, help="window length L (default: the S_L model's, else 5)")
    p.add_argument("--match-len", "--rerank-seq-len", dest="match_len", type=positive_int,
                   help="length L_m of the sequence matchers (default: L; --rerank-seq-len: its earlier name)")
    p.add_argument("--top-k", type=positive_int, help="HVPR shortlist size (default: an index map's stored K, "
                   f"chosen on val or given at build; with --dataset chosen on its val split; else {TOP_K})")
    p.add_argument("--k", type=positive_int, help=f"references ranked per frame, for the confidence (default {_D.k})")
    p.add_argument("--anchor", choices=ANCHORS, help=f"pivot step of vseqmatch / graph (default {_D.anchor}: the "
                   "newest frame, as seqnet eval --window causal)")
    p.add_argument("--split", help="split to replay: train, val, test or all (default: test when defined, else all)")
    p.add_argument("--radius", type=positive_float, help="localisation radius (default: the dataset's)")
    p.add_argument("--precision", choices=tuple(PRECISIONS), help="models and per-frame searches in float32 (default) "
                   "or half precision: float16 / bfloat16 read half the bytes (docs/online.md)")
    add_allow_mismatch(p)
    add_device(p)


def localizer_config(args: argparse.Namespace) -> LocalizeConfig:
    """The :class:`LocalizeConfig` of the options :func:`add_localizer_options` added; without ``--method``, an
    index map's own method (:func:`map_method`), else the default."""
    if args.method is None:
        args.method = map_method(getattr(args, "map", None)) or _D.method
    conf = _D.merge(method=args.method, seq_len=args.seq_len, match_len=args.match_len,
                      top_k=args.top_k, k=args.k, anchor=args.anchor, split=args.split, radius=args.radius,
                      device=args.device, allow_mismatch=args.allow_mismatch or None, precision=args.precision)
    use, args.settings_line = map_settings(getattr(args, "map", None), conf.method, {"top_k": args.top_k})
    return conf.merge(**use)  # the line is said once the map is loaded (a refusal stays one line)


def map_method(where: str | None) -> str | None:
    """The method the index map in ``where`` was built for (``seqnet index build --shortlist --rerank``), said in
    one line when it is not the default; None for anything else (a dataset directory runs every method; a
    damaged map is refused later, when it is loaded)."""
    from ..core.errors import SeqnetError
    from ..core.log import logger
    from ..maps.config import MapConfig
    from ..maps.map import read_meta
    from ..maps.store import MAP_JSON

    if where is None or not (Path(where) / MAP_JSON).is_file():
        return None
    try:
        name = MapConfig.from_dict(read_meta(Path(where))["config"]).method.name
    except (SeqnetError, KeyError, TypeError, ValueError):
        return None
    if name != _D.method:  # the default itself needs no word
        logger.info("--method not given: %s, the method map %s was built for", name, shown(where))
    return name


def add_video_query(p: argparse.ArgumentParser) -> None:
    """The options of a video or stream as --query: --fps, --every-metres, --realtime, --positions, --video-start,
    --plot."""
    p.add_argument("--fps", type=positive_float, metavar="F", help="video query: frames localised per second of video "
                   "(default: as the map's video was sampled, else every frame)")
    p.add_argument("--every-metres", type=positive_float, metavar="M", help="video query with --positions: one frame "
                   "localised per M metres travelled (default: as the map's video was sampled)")
    p.add_argument("--realtime", action="store_true", help="video query: pace a file by its own clock and drop "
                   "frames that come while the localiser is behind (the summary counts them: dropped)")
    p.add_argument("--positions", metavar="FILE", help="video query: its GPS track (GPX, NMEA or CSV with a time "
                   "column), the ground truth: error in metres, correct within --radius")
    p.add_argument("--video-start", metavar="ISO", help="video query: when its first frame was recorded (ISO-8601), "
                   "overriding its creation_time, to join a track of absolute times")
    p.add_argument("--stream", type=int, metavar="N", help="video query: the file's video stream N (0: its first; "
                   "default: the first that is not a cover picture, warned when it holds several)")
    p.add_argument("--timeout", type=positive_float, metavar="SECONDS", help="live stream: seconds it may stall "
                   "before it is given up (default 10)")
    p.add_argument("--plot", metavar="TRACK.png", help="draw the trajectory: the map's route and each estimate on it, "
                   "coloured correct / wrong with --positions (else by confidence)")


def _plotter(path: str | None):  # noqa: ANN202 - a hook or None
    """The ``on_track`` hook that draws the trajectory into ``path`` (None: no plot)."""
    if path is None:
        return None
    if not path.lower().endswith(".png"):
        raise ConfigError(f"--plot {path} must be a .png file")

    def draw(view) -> None:  # noqa: ANN001 - a TrackView
        from ..report.trajectory import write_trajectory

        write_trajectory(view, path, Path(path).stem)

    return draw


def video_options(args: argparse.Namespace) -> VideoOptions:
    """The :class:`VideoOptions` of the parsed options."""
    return VideoOptions(fps=args.fps, every_metres=args.every_metres, realtime=args.realtime,
                        video_start=args.video_start, stream=args.stream,
                        positions=None if args.positions is None else Path(args.positions),
                        **({"timeout": args.timeout} if args.timeout else {}))


def run(args: argparse.Namespace) -> int:
    conf = localizer_config(args)
    if args.describer is not None and args.query is None:
        raise ConfigError("--describer goes with --map and query images (the plug-in the map was described with)")
    if args.topic is not None and args.query is None:
        raise ConfigError("--topic names the image topic of a ROS bag given as --query (with --map)")
    if args.positions_topic is not None and args.query is None:
        raise ConfigError("--positions-topic gives the ground truth of a ROS bag given as --query (with --map); "
                          "--dataset replays a query traverse with its own positions")
    if args.positions_tolerance is not None and args.positions_topic is None:
        raise ConfigError("--positions-tolerance goes with --positions-topic")
    if args.resize is not None and args.query is None:
        raise ConfigError("--resize goes with --map and query images (the size of the map's reference images)")
    if args.map is None and args.plot is not None:
        raise ConfigError("--plot goes with --map and --query (the map's route and the query's estimates)")
    if (args.map is None) != (args.query is None):
        raise ConfigError("--query goes with --map (a map and new data to localise); --dataset replays the "
                          "dataset's own query traverse")
    check_distances(args)
    check_calibration_options(args)
    check_method_options(args, [args.method])
    if args.target_precision is not None and args.map is not None:
        raise ConfigError("--target-precision calibrates on another split of --dataset; with --map calibrate with "
                          "seqnet localize --dataset (or eval) and apply the threshold to the track's confidence")
    if args.map is not None and args.distances is not None:
        raise ConfigError("--distances goes with --dataset (the matrix covers the dataset's query and reference)")
    if args.map is not None:
        query = Query(Path(args.query), args.topic, args.positions_topic,
                      args.positions_tolerance or DEFAULT_TOLERANCE, video_options(args), args.query,
                      query_size(args.resize))
        out = stream(conf, args.map, query, args.out, args.model, args.shortlist_model, args.rerank_model,
                     describer=args.describer, on_track=_plotter(args.plot))
        if args.settings_line:
            print(shown(args.settings_line))
    else:
        out = main(conf, args.dataset, args.out, args.model, args.shortlist_model, args.rerank_model,
                   args.distances, args.similarity, args.transposed, calibration(args),
                   choose=tuple(k for k in SELECTABLE if k != "top_k" or args.top_k is None))
    print_summary(conf, args, out)
    return 0


def query_size(resize: str | None) -> tuple[int, int] | None:
    """``--resize WxH`` as ``(W, H)`` (checked as ``seqnet describe --resize``; only WxH: a size the map's reference
    images have), or None."""
    from ..describe.config import check_size

    if resize is None:
        return None
    size = check_size(resize)
    if not isinstance(size, tuple):
        raise ConfigError(f"--resize {resize}: localize takes WxH, the size of the map's reference images")
    return size


def print_summary(conf: LocalizeConfig, args: argparse.Namespace, out: Written) -> None:
    """What the stage wrote beside the track, in a few lines."""
    s = out.data["summary"]
    lat = s.get("latency_ms", {})
    unknown = f" ({s['no_truth']} of them with no known position: not scored)" if s.get("no_truth") else ""
    print(f"{conf.method}: {s['frames']} frames, {s['full_window']} with a full window{unknown}", end="")
    has = "a positive" if out.data.get("config", {}).get("ground_truth") == "explicit positives" else \
        "a reference within the radius"
    if "recall@1" in s:
        print(f": R@1 {s['recall@1']:.3f} ({s['queries']} with {has}), "
              f"AUC {s['auc']:.3f}, R@100P {s['recall@100p']:.3f}", end="")
    elif "queries" in s:
        print(f": no R@1 (no frame with a full window has {has})", end="")
    print("" if "describe_ms" not in s else f"; describing {s['describe_ms']['median']:.1f} ms per image (median)")
    if "dropped" in s:
        print(f"video: {s['decoded']} frames decoded{_sampled(s.get('sampling'))}, {s['dropped']} dropped"
              + (f", {s['outside']} outside the track" if s.get("outside") else "")
              + (f"; decoding {s['decode_share']:.0%} of the frame time" if "decode_share" in s else ""))
    if args.plot:
        print(f"trajectory plot in {args.plot}")
    print_calibrated(s.get("calibrated"))
    warm = f" (the {lat['warmup_frames']} warm-up frames left out: up to {lat['warmup_max']:.1f} ms)" \
        if lat.get("warmup_frames") else ""
    print(f"latency per frame: mean {lat.get('mean', 0):.2f} ms, median {lat.get('median', 0):.2f} ms, "
          f"p95 {lat.get('p95', 0):.2f} ms, p99 {lat.get('p99', 0):.2f} ms{warm}; track in {out}")


def _sampled(sampling: dict | None) -> str:
    """`` at 5 frames/s (as the map)`` of the summary's ``sampling`` (empty for every frame)."""
    from ..localize.track import Sampling

    if not sampling or (sampling.get("fps") is None and sampling.get("every_metres") is None):
        return ""
    s = Sampling(sampling.get("fps"), sampling.get("every_metres"))
    return f" ({s.said()}{', as the map' if sampling.get('as') == 'map' else ''})"


def calibration(args: argparse.Namespace) -> tuple[float, str, float] | None:
    """``(target precision, calibration split, risk)`` of ``--target-precision`` (checked), or None."""
    if args.target_precision is None:
        return None
    target, risk = check_target(args.target_precision, RISK if args.risk is None else args.risk)
    return target, args.calibrate_split or "val", risk


def print_calibrated(c: dict | None) -> None:
    """What the calibrated threshold gave on the replayed frames (the track's ``accepted`` column)."""
    if c is None:
        return
    cal = c["calibration"]
    head = f"calibrated on {shown(cal['split'])} for precision >= {cal['target']:g} (risk {cal['risk']:g}): "
    if cal["threshold"] is None:
        print(head + f"abstains on every frame ({cal['reason']})")
        return
    print(head + calibrated_result(c, " frames"))
    if c.get("target_met") is False:
        print(missed_target_note(shown(cal["split"])))
