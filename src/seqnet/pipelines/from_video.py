"""Two videos (and their GPS tracks) → a dataset, described consistently: ``seqnet dataset from-video``.

Each video's frames are read with PyAV (:mod:`seqnet.sources.video`), frame by frame, and named by their video
time. With a positions file per video (GPX, NMEA 0183 RMC/GGA, CSV with a time column: :mod:`seqnet.sources.tracks`)
each frame takes the position interpolated at its time, in UTM metres (both in the reference's zone); frames
outside a track are dropped and counted. Frames are kept at ``fps`` per second of video, or one per
``every_metres`` travelled. Without positions, ``aligned`` says frame i of the query shows the place of frame i of
the reference (positions are frame numbers; both videos must keep as many frames, else refused); otherwise
there is no ground truth, and that is an error. Both videos are described with one describer
(:func:`seqnet.pipelines.from_images.write_dataset`): the result is a normal seqnet dataset.
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path

import numpy as np

from ..core.config import Config, check_float
from ..core.errors import ConfigError, DatasetError
from ..data.sanity import VIDEO_ALTERNATIVES
from ..data.utm import frame_zone, mixed_frames
from ..describe import DescribeConfig
from ..describe.images import ImageList
from ..sources.placed import Placed, place_video
from ..sources.tracks.interpolate import DEFAULT_MAX_GAP
from .from_images import FIT_ON, FromImagesConfig, write_dataset


@dataclasses.dataclass(frozen=True)
class FromVideoConfig(Config):
    """Settings of :func:`main`.

    Attributes:
        describe: how both videos' frames are described.
        fps: frames kept per second of video (None: every frame); ignored with ``every_metres``.
        every_metres: one frame kept per this many metres travelled (needs positions).
        aligned: without positions: query frame i shows the place of reference frame i (radius in frames).
        radius: localisation radius (metres with positions, frames when aligned); inclusive.
        video_start: when both videos' first frames were recorded, overriding their ``creation_time`` (ISO-8601);
            ``reference=ISO`` / ``query=ISO`` (comma-separated) for one video or each its own.
        max_gap: seconds between two track samples a frame may be interpolated across.
        fit_on: ``reference`` or ``both``: where PCA / NetVLAD clusters are fitted.
        splits: named half-open ranges of the kept frames ``{name: {"reference": (a, b), "query": (c, d)}}``
            (``--split``, as the other builders: :class:`~seqnet.pipelines.from_images.FromImagesConfig`).
        streams: which video stream of each file (reference, query) is read (None: the first that is not a cover
            picture; :func:`seqnet.sources.video.choose_stream`).
        name: dataset name (None: the output directory's).
    """

    describe: DescribeConfig = DescribeConfig()
    fps: float | None = None
    every_metres: float | None = None
    aligned: bool = False
    radius: float = 25.0
    video_start: str | None = None
    max_gap: float = DEFAULT_MAX_GAP
    fit_on: str = "reference"
    name: str | None = None
    streams: tuple[int | None, int | None] = (None, None)
    splits: dict | None = None

    def __post_init__(self) -> None:
        for key in ("fps", "every_metres"):
            if getattr(self, key) is not None:
                self._set(key, check_float(key, getattr(self, key), 0.0, strict=True))
        self._set("radius", check_float("radius", self.radius, 0.0, strict=True))
        self._set("max_gap", check_float("max_gap", self.max_gap, 0.0, strict=True))
        if self.fit_on not in FIT_ON:
            raise ConfigError(f"--fit-on {self.fit_on!r} is not one of {', '.join(FIT_ON)}")


SIDES = ("reference", "query")


def _starts(conf: FromVideoConfig) -> dict[str, datetime.datetime | None]:
    """Each video's start as ``--video-start`` gives it: ``ISO`` (both videos), or ``reference=ISO`` / ``query=ISO``
    (comma-separated for both; a side not named keeps its container's ``creation_time``)."""
    from ..sources.tracks.clock import parse_start

    text = conf.video_start
    if text is None:
        return dict.fromkeys(SIDES)
    parts = [p.strip() for p in text.split(",")]
    named = [p.partition("=") for p in parts if p.split("=", 1)[0] in SIDES and "=" in p]
    if not named:
        return dict.fromkeys(SIDES, parse_start(text))
    if len(named) != len(parts) or len({side for side, _, _ in named}) != len(named):
        raise ConfigError(f"--video-start {text[:80]!r}: give one ISO-8601 time for both videos, or reference=ISO "
                          "and/or query=ISO, comma-separated, each side once")
    given = {side: parse_start(iso) for side, _, iso in named}
    return {side: given.get(side) for side in SIDES}


def place_both(conf: FromVideoConfig, videos: tuple[str | Path, str | Path],
               positions: tuple[str | Path | None, str | Path | None]) -> tuple[Placed, Placed]:
    """The kept frames of both videos with their positions (the query's in the reference's UTM zone)."""
    if (positions[0] is None) != (positions[1] is None):
        raise ConfigError("give positions for both videos (--ref-positions and --query-positions), or neither "
                          "(with --aligned)")
    if positions[0] is None and not conf.aligned:
        raise ConfigError("ground truth is needed: positions for both videos (--ref-positions FILE "
                          "--query-positions FILE: GPX, NMEA or CSV), or --aligned when query frame i shows the "
                          "place of reference frame i")
    if positions[0] is not None and conf.aligned:
        raise ConfigError("--aligned is for videos without positions; with --ref-positions / --query-positions the "
                          "frames are placed by them")
    kw = {"fps": conf.fps, "every_metres": conf.every_metres, "max_gap": conf.max_gap}
    start = _starts(conf)
    ref = place_video(videos[0], positions[0], stream=conf.streams[0], flag="--ref-stream", side="reference",
                      video_start=start["reference"], **kw)
    qry = place_video(videos[1], positions[1], zone=frame_zone(ref.frame), stream=conf.streams[1],
                      flag="--query-stream", side="query", video_start=start["query"], **kw)
    if ref.frame != qry.frame:
        raise ConfigError(mixed_frames(str(ref.frame), str(qry.frame)))
    if conf.aligned and len(ref.frames) != len(qry.frames):
        raise DatasetError(_unaligned(conf, ref, qry))
    return ref, qry


def _unaligned(conf: FromVideoConfig, ref: Placed, qry: Placed) -> str:
    """Why ``--aligned`` cannot pair the kept frames of ``ref`` and ``qry`` (their counts differ), and what to do."""
    videos = [p.frames[0].video if p.frames else None for p in (ref, qry)]
    seconds = [f"{v.duration:.1f} s" if v else "no frame" for v in videos]
    rates = [f"{len(v) / v.duration:.3g} fps" if v and v.duration > 0 else "?" for v in videos]
    why = (f"--fps {conf.fps:g} keeps frames in proportion to each video's length ({seconds[0]} and {seconds[1]})"
           if conf.fps is not None else f"every frame is kept ({ref.counts['total']} frames at {rates[0]}, "
           f"{qry.counts['total']} at {rates[1]})")
    return (f"--aligned: query frame i is the place of reference frame i, but the reference keeps {len(ref.frames)} "
            f"frames and the query {len(qry.frames)}: {why}, so videos of different frame rates or lengths keep "
            f"different counts and the ground truth cannot line up; nothing written; hint: {VIDEO_ALTERNATIVES}")


def main(conf: FromVideoConfig, reference: str | Path, query: str | Path, out: str | Path,
         positions: tuple[str | Path | None, str | Path | None] = (None, None), overwrite: bool = False) -> Path:
    """Read, place and describe the videos ``reference`` and ``query`` (with the positions files ``positions``, or
    frame-aligned) and write the dataset directory ``out``; returns it."""
    ref, qry = place_both(conf, (reference, query), positions)
    images = tuple(ImageList(list(p.frames), p.names) for p in (ref, qry))
    if ref.positions is None:
        pos = tuple((np.arange(len(p.frames), dtype=np.float64)[:, None], None) for p in (ref, qry))
        unit = ("frames", None)
    else:
        pos = ((ref.positions, None), (qry.positions, None))
        unit = ("metres", ref.frame)
    inner = FromImagesConfig(describe=conf.describe, fit_on=conf.fit_on, radius=conf.radius, name=conf.name,
                             ground_truth="frames" if conf.aligned else "csv", splits=conf.splits)
    extra = {"ground_truth": "aligned" if conf.aligned else "positions",
             "videos": {side: {"path": str(Path(v).resolve()), "stream": p.stream, "frames": p.counts,
                               **({"positions": str(Path(f).resolve()), "track_times": p.track_times}
                                  if f is not None else {})}
                        for side, v, p, f in zip(("reference", "query"), (reference, query), (ref, qry), positions,
                                                 strict=True)},
             "sampling": {"fps": conf.fps, "every_metres": conf.every_metres}}
    return write_dataset(inner, images, pos, unit, out, overwrite, None, extra)
