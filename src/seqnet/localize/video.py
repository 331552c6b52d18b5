"""A video file or a live stream as the query of ``seqnet localize --map``: frames decoded one by one
(:class:`seqnet.sources.stream.FrameStream`: ``--fps``, ``--realtime`` pacing and drops), each described by the
map's describer, and ground truth from a GPS track (``--positions``: GPX, NMEA, CSV), interpolated at each frame's
time in the map's UTM zone; frames outside the track have no ground truth (counted, ``outside``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..methods.protocol import Reference
from .describing import map_describer
from .replay import frame_truth
from .track import Sampling, place_track, resolve_sampling
from .truth import MapFrame, check_frame

if TYPE_CHECKING:
    from ..sources.placed import JoinedTrack
    from ..sources.stream import FrameStream


def is_video_query(name: str) -> bool:
    """Whether ``--query`` names a video file or a live stream (a URL, ``/dev/videoN``)."""
    from ..security.videos import is_stream_name
    from ..sources.video import is_video

    return is_stream_name(name) or is_video(name)


@dataclasses.dataclass(frozen=True)
class VideoOptions:
    """How a video query is read: ``fps`` kept per second or one frame per ``every_metres`` travelled (neither: as
    the map's video was sampled, :func:`seqnet.localize.track.resolve_sampling`), ``realtime`` pacing, a
    ``positions`` track for ground truth (``video_start``: when the video's first frame was recorded, ISO-8601),
    the stall ``timeout`` (s), which video ``stream`` of a file (None: the first that is not a cover picture)."""

    fps: float | None = None
    every_metres: float | None = None
    realtime: bool = False
    positions: Path | None = None
    video_start: str | None = None
    timeout: float = 10.0
    stream: int | None = None


class VideoQuery:
    """The frames of a video query, described as they come; after them, their ground truth and figures."""

    def __init__(self, name: str, opts: VideoOptions, ref_map: Reference, allow: bool,
                 describer: str | None = None, map_dir: str | Path | None = None,
                 resize: tuple[int, int] | None = None, recorded: Sampling | None = None) -> None:
        from ..sources.stream import FrameStream

        self.name, self.opts = name, opts
        self.describer, self._check = map_describer(ref_map, allow, describer, map_dir, resize)
        self.sampling = resolve_sampling(opts.fps, opts.every_metres, recorded, opts.positions is not None)
        self.source: FrameStream = FrameStream(name, self.sampling.fps, opts.realtime, opts.timeout,
                                                 stream=opts.stream)
        self.track: JoinedTrack | None = None  # a video file's --positions, joined before any frame (prepare)
        self.kept: np.ndarray | None = None  # the video times --every-metres keeps (None: sampled by time)
        self.names: list[str] = []
        self.times: list[float] = []
        self.describe_ms: list[float] = []
        self.counts: dict[str, int] = {}

    def frames(self) -> Iterator[tuple[np.ndarray, float]]:
        """``(descriptor [D], milliseconds describing it)`` of each frame kept, in order."""
        d = self.describer
        kept = self.kept
        tol = 0.25 / (float(self.source.stream.average_rate or 0) or 30.0)
        for f in self.source:
            if kept is not None and not _near(kept, f.time, tol):
                continue
            t0 = time.perf_counter()
            out = d(d.load([f]))
            ms = (time.perf_counter() - t0) * 1e3
            self._check(out, f"the frames of {self.name} as described here")
            self.names.append(f.name)
            self.times.append(f.time)
            self.describe_ms.append(ms)
            yield out[0], ms

    def prepare(self, mf: MapFrame, map_path: str | Path, r_pos: np.ndarray, radius: float) -> None:
        """Before any frame: a video file's track (``--positions``) checked to be in the map's frame, to place some
        frames and to pass near the map's route (:func:`place_track`), and the frames ``--every-metres`` keeps."""
        if self.opts.positions is None or self.source.live:
            if self.sampling.every_metres is not None:
                raise ConfigError("--every-metres samples a video file by its track (--positions FILE), not a live "
                                  "stream: give --fps")
            return
        from ..data.utm import frame_zone

        self.track, self.kept = place_track(
            self.name, self.opts.positions, self._start(), frame_zone(mf.frame), r_pos, radius,
            self.sampling.every_metres, stream=self.source.stream_number,
            on_frame=lambda frame: check_frame(mf, frame, map_path, str(self.opts.positions)))

    def _start(self) -> Any:
        """When the video's first frame was recorded: ``--video-start``, else the video's own (None: unknown)."""
        from ..sources.tracks.clock import parse_start

        return parse_start(self.opts.video_start) if self.opts.video_start else self.source.start

    def truth(self, mf: MapFrame, map_path: str | Path, r_pos: np.ndarray, radius: float, best: np.ndarray,
              frames: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """``(correct [N], has_positive [N], positions [N, 2])`` of the frames localised (None without
        ``positions``; ``frames``: every map frame's position, :func:`.replay.frame_truth`'s); a frame outside the
        track has no positive (and a NaN position). A near-constant time
        offset between the estimates and the track when most frames are wrong is warned (:func:`clock_offset`)."""
        if self.opts.positions is None:
            return None, None, None
        times = np.asarray(self.times, np.float64)
        if self.track is None:  # a live stream: its track is joined to the frames' times once they are known
            from ..data.utm import frame_zone
            from ..sources.placed import track_positions

            duration = float(times[-1]) + 1.0 if len(times) else 0.0
            q_pos, inside, frame = track_positions(self.opts.positions, times, self._start(), duration,
                                                   frame_zone(mf.frame))
            check_frame(mf, frame, map_path, str(self.opts.positions))
        else:
            q_pos, inside = self.track.at(times)
        correct, has = np.zeros(len(times), bool), np.zeros(len(times), bool)
        if inside.any():
            correct[inside], has[inside] = frame_truth(q_pos[inside], r_pos, radius, best[inside], frames=frames)
        self.counts["outside"] = int((~inside).sum())
        from ..data.trajectory import answer_positions
        from ..sources.tracks.offset import clock_offset, mostly_wrong, offset_note

        if self.track is not None and mostly_wrong(correct[has]):
            est = answer_positions(r_pos, best)
            note = offset_note(clock_offset(times, est, self.track.times, self.track.xy), not self.track.absolute)
            if note:
                logger.warning("%s", note)
        return correct, has, q_pos

    def summary(self, latency_ms: np.ndarray) -> dict[str, Any]:
        """The summary's entries of a video query: frames decoded, dropped, outside the track, and per-frame decode,
        describe and match times (ms) with decoding's share of the frame time, and how the video was sampled."""
        dec = np.asarray(self.source.decode_ms, np.float64)
        total = dec.mean() + np.mean(self.describe_ms) + np.mean(latency_ms) if len(dec) else 0.0
        stats = {k: {"mean": float(np.mean(v)), "median": float(np.median(v))}
                 for k, v in (("decode_ms", dec), ("describe_ms", self.describe_ms)) if len(v)}
        sampling = {"fps": self.sampling.fps, "every_metres": self.sampling.every_metres, "as": self.sampling.source}
        return {"decoded": self.source.decoded, "dropped": self.source.dropped, **self.counts, **stats,
                "sampling": sampling,
                **({"decode_share": float(dec.mean() / total)} if total > 0 else {})}


def _near(sorted_times: np.ndarray, t: float, tol: float) -> bool:
    """Whether ``t`` is within ``tol`` of one of ``sorted_times [K]``."""
    i = int(np.searchsorted(sorted_times, t))
    return any(0 <= j < len(sorted_times) and abs(sorted_times[j] - t) <= tol for j in (i - 1, i))


def check_options(opts: VideoOptions, video: bool, query: str) -> None:
    """Refuse the video options with a query that is not a video or stream."""
    if video:
        return
    for flag, value in (("--fps", opts.fps), ("--every-metres", opts.every_metres),
                        ("--realtime", opts.realtime or None), ("--positions", opts.positions),
                        ("--stream", opts.stream),
                        ("--video-start", opts.video_start)):
        if value is not None:
            hint = "; hint: for images with positions, build a dataset (seqnet dataset from-images REF QUERY " \
                "--ref-csv REF.csv --query-csv QUERY.csv) and replay its query with seqnet localize --dataset DS" \
                if flag == "--positions" else ""
            raise ConfigError(f"{flag} goes with a video file or a live stream as --query, but {query} is "
                              f"neither{hint}")
