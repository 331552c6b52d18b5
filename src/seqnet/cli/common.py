"""Argument helpers shared by CLI commands."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from ..core.errors import ConfigError
from ..metrics.recall import RECALL_DENOMINATORS


def int_at_least(minimum: int):
    """argparse type factory: an integer ≥ ``minimum``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {v}")
        return v

    return parse


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (v > 0 and v != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return v


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (v >= 0 and v != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text}")
    return v


def int_list(text: str) -> tuple[int, ...]:
    """argparse type: comma-separated integers >= 1 (e.g. ``1,5,10``)."""
    try:
        values = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers (e.g. 1,5,10), got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected integers >= 1, got {text!r}")
    return values


def index_range(text: str) -> tuple[int, int]:
    """argparse type: ``START:STOP`` (half-open index range)."""
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP (e.g. 0:1650), got {text!r}") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"expected 0 <= START < STOP, got {text!r}")
    return a, b


def speed_range(text: str) -> tuple[float, float]:
    """argparse type: ``A:B`` with ``0 < A <= B`` (a speed range: ``--query-speed``, ``--speed-augment``)."""
    from ..sequence.windows import check_speed_range

    try:
        return check_speed_range("speed", [float(x) for x in text.split(":")])
    except (ValueError, ConfigError) as e:
        raise argparse.ArgumentTypeError(f"expected A:B with 0 < A <= B (e.g. 0.5:2), got {text!r}") from e


def add_recall_denominator(p: argparse.ArgumentParser, default: str) -> None:
    """``--recall-denominator``: which queries Recall@K is over (:data:`RECALL_DENOMINATORS`; ``default``: the
    command's configuration's)."""
    p.add_argument("--recall-denominator", choices=list(RECALL_DENOMINATORS),
                   help="Recall@K over: " + "; ".join(f"{k}: {v}" for k, v in RECALL_DENOMINATORS.items())
                   + f" (default {default}, the original code's)")


def add_device(p: argparse.ArgumentParser) -> None:
    """``--device`` (auto: CUDA when present)."""
    p.add_argument("--device", default="auto", help="torch device: auto (GPU when present), cpu, cuda, cuda:1 ...")


def parse_list(values: Sequence[str] | None, valid: Sequence[str] | None = None, what: str = "value") -> list[str]:
    """Split comma-separated CLI values and check them against ``valid``."""
    out = [v.strip() for item in (values or []) for v in item.split(",") if v.strip()]
    if values and not out:
        raise ConfigError(f"no {what} in {values!r}; give at least one (comma-separated)")
    if valid is not None:
        for v in out:
            if v not in valid:
                raise ConfigError(f"unknown {what} {v!r}; valid: {', '.join(valid)}")
    return out


def drop_none(d: dict[str, Any]) -> dict[str, Any]:
    """The entries of ``d`` whose value is not None."""
    return {k: v for k, v in d.items() if v is not None}


def add_allow_mismatch(p: argparse.ArgumentParser) -> None:
    """``--allow-mismatch``: go on when descriptors or models were made differently (experts)."""
    p.add_argument("--allow-mismatch", action="store_true",
                   help="go on (with a warning) when reference and query descriptors, or a model and the "
                        "descriptors, were made with different settings")


def add_topic(p: argparse.ArgumentParser, what: str = "IMAGES") -> None:
    """``--topic``: the image topic of a ROS bag given as ``what`` (docs/online.md, ROS bags)."""
    p.add_argument("--topic", metavar="TOPIC", help=f"when {what} is a ROS bag (ROS 1 .bag, ROS 2 bag directory or "
                   "its .db3 / .mcap file): its image topic (sensor_msgs/Image rgb8, bgr8, mono8, or "
                   "CompressedImage jpeg/png), read in timestamp order, frames named by their timestamp in ns; "
                   "needs seqnet[ros]")


def add_distances(p: argparse.ArgumentParser, use: str) -> None:
    """``--distances FILE.npy`` and ``--similarity``: a precomputed ``[N_query, N_reference]`` matrix of the
    dataset's frames (VPR-Bench, VPR_Tutorial, any tool) in place of descriptors; ``use``: what the command
    does with it (docs/own_data.md)."""
    p.add_argument("--distances", metavar="FILE.npy", help="a precomputed [N_query, N_reference] frame-distance "
                   f"matrix of the dataset (from VPR-Bench, VPR_Tutorial, any tool) instead of descriptors, {use}; "
                   "methods: single, raw+seqmatch(-rev), raw+vseqmatch(-rev), raw+graph, "
                   "hvpr-single:raw+seqmatch(-rev)")
    p.add_argument("--similarity", action=argparse.BooleanOptionalAction, default=None,
                   help="--distances holds similarities (higher is closer); --no-similarity: distances, said for a "
                   "VPR-Bench file, whose matrix holds similarities unless you say otherwise")
    p.add_argument("--transposed", action="store_true", help="--distances is [N_reference, N_query], one row per "
                   "reference frame (VPR_Tutorial's S)")


def check_distances(args: argparse.Namespace) -> None:
    """``--similarity`` and ``--transposed`` describe the ``--distances`` matrix: refused without one."""
    for flag in ("similarity", "transposed"):
        if getattr(args, flag) and not args.distances:
            raise ConfigError(f"--{flag} describes the --distances matrix; give --distances FILE.npy")


def check_method_options(args: argparse.Namespace, methods: list[str] | None) -> None:
    """Options of one method given to methods that cannot use them are refused before work (``methods``: those
    named with --method; None: the defaults, which include every kind the models allow)."""
    if not methods or args.distances:
        return
    from ..methods.grammar import parse_method

    parsed = [parse_method(n) for n in methods]
    uses = {"--top-k": any(m.kind == "hvpr" and not m.fused for m in parsed),
            "--fuse-weight": any(m.fused for m in parsed), "--fuse-top-k": any(m.fused for m in parsed),
            "--match-len": any(m.matcher for m in parsed)}
    why = {"--top-k": "the HVPR shortlist size (hvpr-fused takes --fuse-top-k)",
           "--fuse-weight": "hvpr-fused's weight", "--fuse-top-k": "hvpr-fused's shortlist size",
           "--match-len": "the length L_m of a sequence matcher (+seqmatch, +graph, hvpr ...)"}
    given = {flag: getattr(args, flag[2:].replace("-", "_"), None) for flag in uses}
    for flag, value in given.items():
        if value is not None and not uses[flag]:
            raise ConfigError(f"{flag} is {why[flag]}; none of the methods given ({', '.join(methods)}) uses it: "
                              f"drop {flag} or add a method that does")


def add_calibration_options(p: argparse.ArgumentParser) -> None:
    """``--target-precision``, ``--calibrate-split``, ``--risk``: a confidence threshold calibrated on another
    split, with a promise (:mod:`seqnet.metrics.calibration`)."""
    p.add_argument("--target-precision", type=float, metavar="P", help="accept or abstain per query: calibrate on "
                   "--calibrate-split a confidence threshold whose precision is >= P with probability >= 1 - "
                   "--risk on new queries from the same distribution (declined, with the reason, when that split is "
                   "too small: 299 queries at P = 0.99), and report what it accepts on the evaluated split and the "
                   "precision achieved, with its interval (docs/online.md)")
    p.add_argument("--calibrate-split", metavar="SPLIT", help="with --target-precision: the split it is calibrated "
                   "on (a split name or a range A:B; default val); it must not overlap the evaluated split")
    p.add_argument("--risk", type=float, metavar="R", help="with --target-precision: the probability that the "
                   "promise fails (default 0.05; at most 0.5: a risk, not a confidence level)")


def check_calibration_options(args: argparse.Namespace) -> None:
    """``--calibrate-split`` and ``--risk`` go with ``--target-precision``."""
    if args.target_precision is None and (args.calibrate_split is not None or args.risk is not None):
        raise ConfigError("--calibrate-split and --risk go with --target-precision P")


def calibrated_result(c: dict[str, Any], what: str = "") -> str:
    """What a calibrated threshold gave (:func:`seqnet.metrics.calibration.apply_threshold`'s entry ``c``):
    'confidence >= 0.31 accepts 720 of 817 (88.1%), precision 1.000 [0.996, 1.000] (90% interval), recall
    0.881', ending '— BELOW the target 0.99' when the measured precision missed it. ``what``: the items' word."""
    cal = c["calibration"]
    lo, hi = c["precision_interval"] or (float("nan"), float("nan"))
    level = f"{100 * (1 - cal['risk']):g}% interval"
    prec = "–" if c["precision"] is None else f"{c['precision']:.3f} [{lo:.3f}, {hi:.3f}] ({level})"
    missed = f" — BELOW the target {cal['target']:g}" if c.get("target_met") is False else ""
    return (f"confidence >= {cal['threshold']:.4g} accepts {c['accepted']} of {c['queries']}{what} "
            f"({100 * c['accepted_fraction']:.1f}%), precision {prec}, recall {c['recall']:.3f}{missed}")


def missed_target_note(calibrate_split: str, on_training: bool = False) -> str:
    """Why a measured precision can fall below the target, and what to do (printed once under the results);
    ``on_training``: the calibration split holds queries the models were trained on (warned before), the cause
    named first."""
    if on_training:
        return (f"  (measured below the target: {calibrate_split} holds queries the models were trained on (warned "
                "above), where they are right more often and surer than on new queries, so its threshold promises "
                "too much; calibrate on queries apart from training, as the warning's hint says)")
    return (f"  (measured below the target: the promise is for queries drawn like those of {calibrate_split}, and "
            "fails with probability risk, or by chance on few queries; a gap beyond the interval means the "
            "evaluated queries differ from them, e.g. a harder stretch of the route: calibrate on queries like "
            "the ones you will localise)")
