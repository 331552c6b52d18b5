"""``seqnet localize --map MAP --query DESCRIPTORS_OR_IMAGES``: localise new data frame by frame.

The map is what :func:`load_reference` returns: an index map (``seqnet index build --window causal``;
:mod:`seqnet.maps`: its stored descriptors and ANN index are used), or a seqnet dataset
directory whose reference traverse (optionally one split) is the map. The query is either a
descriptor file (``.npy`` with its provenance sidecar, ``.h5``), a folder / list file of images, or a ROS
bag's image topic (frames in timestamp order, named by their timestamp), described one by one as they are
read, by the describer the map was described with (rebuilt from the map's provenance, with the dataset's
train-split PCA of ``--pca D`` applied: :func:`seqnet.localize.describing.map_describer`; a describer with fitted
state of its own — ``--dim``, NetVLAD clusters — is not rebuilt: describe the images with ``seqnet describe``
fitted on the same images and pass the file). Either way the query's provenance must match the
map's (:func:`seqnet.core.provenance.check_same`).
Without ground truth the ``correct`` column is empty.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError, SeqnetError
from ..core.log import counted, logger
from ..core.progress import progress
from ..core.stage import Written
from ..data.readers import DESCRIPTOR_SUFFIXES
from ..data.trajectory import TrackView
from ..eval.config import EvalConfig
from ..methods.protocol import Reference
from ..security.dirs import remove_dead_temps
from ..security.inputs import special_file
from ..security.limits import number
from ..security.locks import locked
from ..sources.bags.positions import DEFAULT_TOLERANCE

if TYPE_CHECKING:
    from ..describe.images import ImageList
    from ..maps.map import Map

from .config import LocalizeConfig
from .copies import CopyWatch, reference_rows
from .describing import check_not_dataset
from .frames import Frames, descriptor_frames, image_frames
from .localizer import Estimate, traverse_reference
from .order import QueryOrder, order_note, short_query_note
from .replay import frame_truth, summarize
from .trackfile import FrameTruth, check_output, sidecar_of, track_rows, write_track
from .truth import MapFrame, check_frame, query_positions
from .video import VideoOptions, VideoQuery, check_options, is_video_query

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


def load_reference(path: str | Path, models: Mapping[str, SeqNet],
             conf: LocalizeConfig) -> tuple[Reference, float, MapFrame]:
    """The map in ``path`` as a reference, with its radius and the frame of its positions: an index map (``seqnet
    index build --window causal``; its L, L_m and models), or a dataset directory whose reference traverse
    (``conf.split``, default all) is the map."""
    from ..data.io import load_dataset
    from ..maps import load_map as load_index_map
    from ..maps.store import MAP_JSON

    if not (Path(path) / MAP_JSON).is_file():
        ds = load_dataset(path).split(conf.split or "all")
        ref = traverse_reference(ds.reference, models, conf.method, conf.windows(models), get_device(conf.device),
                                 conf.allow_mismatch, ds.name)
        return ref, conf.radius or ds.radius, dataclasses.replace(MapFrame.of(ds.extra), unit=ds.position_unit)
    if models:
        raise ConfigError(f"{path} is an index map: it stores the models its descriptors were made with; drop "
                          "--model / --shortlist-model / --rerank-model")
    if conf.split is not None:
        raise ConfigError(f"{path} is an index map of one split already; drop --split")
    mp = load_index_map(path, conf.device, conf.anchor)
    source = mp.meta.get("source") if isinstance(mp.meta.get("source"), dict) else {}
    return (*index_reference(mp, conf), MapFrame.of(source))


def index_reference(mp: Map, conf: LocalizeConfig) -> tuple[Map, float]:
    """An index map checked for the localiser (causal windows, ``conf``'s method, L and L_m), as that method
    searches it (:meth:`seqnet.maps.Map.for_method`: a single-frame method searches every reference frame), with its
    radius (``conf.radius``, else the radius of the dataset it was built from)."""
    from ..maps.evaluate import check_conf
    from ..methods.grammar import parse_method

    if mp.config.window != "causal":
        raise ConfigError(f"map {mp.path} was built with {mp.config.window} windows; the online localiser needs "
                          "causal ones (seqnet index build --window causal)")
    check_conf(mp, EvalConfig(methods=(conf.method,), seq_len=conf.seq_len, match_len=conf.match_len,
                              window="causal"))
    source = mp.meta.get("source") if isinstance(mp.meta.get("source"), dict) else {}
    radius = conf.radius or source.get("radius")
    if radius is None:
        raise ConfigError(f"map {mp.path} records no localisation radius; give one (--radius)")
    return mp.for_method(parse_method(conf.method)), float(number(radius, f"map {mp.path}: radius", 1e-300, 1e300,
                                                                  ConfigError, integer=False))


@dataclasses.dataclass(frozen=True)
class Query:
    """What ``seqnet localize --map`` streams: ``path`` (a descriptor file, images, or a ROS bag's image ``topic``)
    and, for a bag, the ``positions_topic`` giving each frame's ground truth within ``tolerance`` seconds;
    ``resize``: images described at this ``(W, H)``, the size of the reference images of a map described at their
    own size (:func:`seqnet.localize.describing.map_describer`)."""

    path: Path
    topic: str | None = None
    positions_topic: str | None = None
    tolerance: float = DEFAULT_TOLERANCE
    video: VideoOptions = VideoOptions()
    name: str | None = None  # as given (a URL keeps its '//'); None: str(path)
    resize: tuple[int, int] | None = None  # --resize: the size of a native-size map's reference images

    @property
    def shown(self) -> str:
        """The query as named."""
        return self.name or str(self.path)


def stream(conf: LocalizeConfig, map_dir: str | Path, query: str | Path | Query, out: str | Path,
           models: Sequence[str | Path] = (), shortlist_model: str | Path | None = None,
           rerank_model: str | Path | None = None, topic: str | None = None, describer: str | None = None,
           on_track: Callable[[TrackView], None] | None = None) -> Written:
    """hloc-style stage: localise every frame of ``query`` (``topic``: the image topic of the ROS bag ``query``; a
    :class:`Query` names its positions topic too) against the map in ``map_dir`` with the model checkpoints given;
    writes ``out`` (track.csv) and its ``.json`` summary (with ground truth: R@1, AUC, R@100P); returns ``out``. The
    track is locked for the whole run (a second writer: exit 1). ``describer``: the plug-in describer the user
    trusts (:func:`seqnet.localize.describing.check_named_code`). ``on_track``: called with the
    :class:`TrackView` of the track written (e.g. to draw it)."""
    q = query if isinstance(query, Query) else Query(Path(query), topic)
    with locked(check_output(out)):
        remove_dead_temps([Path(out), sidecar_of(Path(out))])
        return _stream(conf, map_dir, q, Path(out), models, shortlist_model, rerank_model, describer, on_track)


def query_images(q: Query) -> tuple[bool, ImageList | None, np.ndarray | None]:
    """``(is a descriptor file, its images, their positions [N, 2])`` of the query, every refusal of the query's
    inputs (a pipe, a topic, a positions topic and its tolerance) before any work."""
    from ..describe.images import list_images

    if special_file(q.path):  # --query <(...): a pipe is read once, and frames are read as they come
        raise ConfigError(f"--query {q.path} is a {special_file(q.path)}, not a file or folder; save the descriptors "
                          "or images to a file (or folder) first")
    is_file = q.path.is_file() and q.path.suffix.lower() in DESCRIPTOR_SUFFIXES
    for flag, value in (("--topic", q.topic), ("--positions-topic", q.positions_topic)):
        if is_file and value is not None:
            raise ConfigError(f"{flag} {value} goes with a ROS bag as --query, but {q.path} is a descriptor file")
    if is_file and q.resize is not None:
        raise ConfigError(f"--resize goes with query images (a folder, a list file, a bag, a video), but {q.path} "
                          "is a descriptor file")
    if is_file:
        return True, None, None
    check_not_dataset(q.path)
    images = list_images(q.path, q.topic, q.positions_topic)  # a wrong source or topic first: the user's to fix
    positions = None if q.positions_topic is None else query_positions(images, q.tolerance, q.path)
    return False, images, positions


def _stream(conf: LocalizeConfig, map_dir: str | Path, q: Query, out: Path, models: Sequence[str | Path],
            shortlist_model: str | Path | None, rerank_model: str | Path | None, describer: str | None,
            on_track: Callable[[TrackView], None] | None = None) -> Written:
    from ..sequence.checkpoints import load_models

    video = is_video_query(q.shown) and q.topic is None
    check_options(q.video, video, q.shown)
    is_file, images, q_pos = (False, None, None) if video else query_images(q)
    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    ref_map, radius, frame = load_reference(map_dir, loaded, conf)
    if q_pos is not None:
        check_frame(frame, images.positions.frame, map_dir, q.positions_topic)
    loc = conf.localizer(ref_map, radius)
    vq = VideoQuery(q.shown, q.video, ref_map, conf.allow_mismatch, describer, map_dir, q.resize,
                    frame.sampling) if video else None
    if vq is not None:
        vq.prepare(frame, map_dir, loc.r_pos, radius)
    frames, names, n = ((vq.frames(), vq.names, None) if vq else
                        descriptor_frames(q.path, ref_map, conf.allow_mismatch, map_dir) if is_file else
                        image_frames(q.path, images, ref_map, conf.allow_mismatch, describer, map_dir, q.resize))
    order = QueryOrder()
    est, describe_ms = _localise(loc, order.watch(frames), n, conf.method,
                                 lambda e: _write_partial(out, e, names, ref_map))
    best, every = np.array([e.ref_index for e in est], dtype=np.int64), ref_map.positions  # every: all map frames
    correct, has = (None, None) if q_pos is None else frame_truth(q_pos, loc.r_pos, radius, best, None, every)
    if vq is not None:
        correct, has, q_pos = vq.truth(frame, map_dir, loc.r_pos, radius, best, every)
    known = _known(q_pos)
    summary = summarize(est, correct, has, known)
    if not is_file and describe_ms:
        summary["describe_ms"] = {"mean": float(np.mean(describe_ms)), "median": float(np.median(describe_ms))}
    if vq is not None:
        summary.update(vq.summary(np.array([e.latency_ms for e in est])))
    record = {"summary": summary, "config": {**conf.for_reference(ref_map).to_dict(), "seq_len": loc.seq_len,
                                             "match_len": loc.match_len, "radius": radius},
              "inputs": {"map": str(Path(map_dir).resolve()), **_query_inputs(q, images),
                         "models": [str(Path(p).resolve()) for p in (*models, shortlist_model, rerank_model) if p]},
              "provenance": {"map": ref_map.provenance,
                             "models": {r: m.provenance for r, m in loaded.items()}}}
    record.update(_notices(loc, est, conf.method, len(ref_map.positions), order, getattr(ref_map, "meta", None)))
    truth = FrameTruth.of(q_pos, loc.r_pos, best, frame.unit)
    if truth is not None:
        record["truth"] = truth.record()
    write_track(check_output(out), track_rows(est, names, ref_map.names, correct, truth=truth, known=known),
                record)
    logger.debug("localize: %d frames streamed", len(est))
    if on_track is not None:
        on_track(TrackView.of(ref_map.positions, loc.r_pos, best, np.array([e.confidence for e in est]), q_pos,
                              correct, has, frame.unit, radius))
    return Written(out, record)


def _notices(loc: Any, est: Sequence[Estimate], name: str, map_frames: int, order: QueryOrder,
             meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """What the estimates of a sequence method say about the query (:mod:`seqnet.localize.order`): shorter than
    its window, or not in capture order; and a query far longer than an index map (``meta``: its ``map.json``) of
    part of its dataset's route (:func:`seqnet.maps.coverage.partial_map_note`); each line logged once as a
    warning, the summary's ``warnings``."""
    from ..maps.coverage import partial_map_note

    lines = [line for line in (short_query_note(est, loc.method, name, loc.windows.longest),
                               order_note(est, loc.method, loc.seq_len, map_frames, order),
                               partial_map_note(meta, loc.ref.name, len(est))) if line]
    for line in lines:
        logger.warning("%s", line)
    return {"warnings": lines} if lines else {}


def _known(q_pos: np.ndarray | None) -> np.ndarray | None:
    """``[Nq]``: whether each frame's true position ``q_pos [Nq, P]`` is known (a NaN row: a video's frame outside
    its track); None without ground truth."""
    if q_pos is None:
        return None
    q = np.isfinite(np.asarray(q_pos, np.float64))
    return q.all(axis=1) if q.ndim > 1 else q


def _localise(loc: Any, frames: Frames, n: int | None, method: str,
              partial: Callable[[list[Estimate]], Path | None]) -> tuple[list[Estimate], list[float]]:
    """``(estimates, describe_ms)`` of every frame; a frame that fails (an image of another size, a damaged one)
    ends the run with its error, after ``partial`` wrote the track of the frames localised before it. The map's own
    frames given as the query are said (:class:`~seqnet.localize.copies.CopyWatch`)."""
    est: list[Estimate] = []
    describe_ms = []
    copies = CopyWatch(reference_rows(loc.ref))
    try:
        for d, ms in progress(copies.watch(frames), desc=f"localize ({method})", total=n, unit="frame"):
            est.append(loc.step(d))
            describe_ms.append(ms)
    except SeqnetError as e:
        written = partial(est) if est else None
        if written is None:
            raise
        e.args = (f"{e} (the track of the {counted(len(est), 'frame')} localised before it is written: {written})",)
        raise
    note = copies.note()
    if note:
        logger.warning("%s", note)
    return est, describe_ms


def _write_partial(out: Path, est: list[Estimate], names: Sequence[str] | None, ref_map: Reference) -> Path | None:
    """Write the track of the frames ``est`` localised before a failure (as a whole track is written, without
    ground truth: its summary says ``partial``); None when it cannot be written (the failure is said alone)."""
    try:
        rows = track_rows(est, list(names)[:len(est)] if names is not None else None, ref_map.names, None)
        return write_track(check_output(out), rows, {"summary": {**summarize(est, None, None), "partial": True}})
    except (SeqnetError, OSError) as e:
        logger.debug("the track of the frames done was not written: %s", e)
        return None


def _query_inputs(q: Query, images: ImageList | None) -> dict[str, Any]:
    """The query's entries of the summary's ``inputs``: its path, topic, positions topic and frame."""
    name = q.name if q.name and is_video_query(q.name) and not q.path.exists() else str(q.path.resolve())
    out: dict[str, Any] = {"query": name, **({"topic": q.topic} if q.topic else {})}
    if q.video.positions is not None:
        out["positions"] = str(Path(q.video.positions).resolve())
    if q.positions_topic is not None and images is not None and images.positions is not None:
        out.update(positions_topic=q.positions_topic, positions_tolerance=q.tolerance,
                   positions_frame=images.positions.frame)
    return out
