"""The ``seqnet localize`` stage: replay a dataset's query traverse frame by frame through a :class:`Localizer`.

Writes ``track.csv`` (one row per query frame, :data:`TRACK_COLUMNS`) and beside it ``track.json``
(the resolved config, the inputs and their provenance, and a summary: R@1, AUC and R@100P over the
frames with a full causal window — the numbers ``seqnet eval --window causal`` gives — and the
per-frame latency).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.progress import progress
from ..core.stage import Written
from ..data.traverse import Dataset, default_split
from ..eval.calibrated import check_calibration_split
from ..metrics.calibration import accepted, apply_threshold, calibrate
from ..metrics.precision_recall import pr_summary, precision_recall
from ..metrics.recall import ground_truth
from ..security.digests import file_digest
from ..security.dirs import remove_dead_temps
from ..security.locks import locked
from ..security.text import shown
from .config import TOP_K, LocalizeConfig
from .localizer import Estimate, Localizer, online_method, replay, traverse_reference
from .trackfile import FrameTruth, check_output, sidecar_of, track_rows, write_track

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..data.positives import Positives
    from ..sequence.model import SeqNet



def dataset_localizer(ds: Dataset, models: Mapping[str, SeqNet], conf: LocalizeConfig) -> Localizer:
    """The localiser of ``conf`` over the reference traverse of ``ds`` (radius: ``conf.radius`` or the dataset's)."""
    ref = traverse_reference(ds.reference, models, conf.method, conf.windows(models), get_device(conf.device),
                             conf.allow_mismatch, ds.name)
    return conf.localizer(ref, conf.radius or ds.radius)


def replay_query(loc: Localizer, ds: Dataset, frames: np.ndarray | None = None) -> list[Estimate]:
    """Every frame of the query traverse (or ``frames [Nq, D]`` in its place) through ``loc`` (a progress
    bar), resetting at sequence starts."""
    return list(progress(replay(loc, ds.query, frames), desc=f"localize ({loc.method.name})", total=len(ds.query),
                         unit="frame"))


def track_truth(ds: Dataset, ref_items: np.ndarray, radius: float, best: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(correct [Nq], has_positive [Nq])`` of the top-1 reference items ``best`` (-1: none) of every query frame; a
    frame whose correct references are all reference frames outside ``ref_items`` (no full window fits there) has
    one, and its answer is wrong (as the evaluation counts it: :attr:`seqnet.metrics.recall.GroundTruth.matched`)."""
    positives = ds.positives.select(np.arange(len(ds.query)), ref_items) if ds.positives is not None else None
    outside = ds.positives is not None and len(ref_items) < len(ds.reference)  # explicit positives of frames no item
    return frame_truth(ds.query.positions, ds.reference.positions[ref_items], radius, best, positives,
                       frames=ds.reference.positions, matched=ds.positives.counts() > 0 if outside else None)


def frame_truth(q_pos: np.ndarray, r_pos: np.ndarray, radius: float, best: np.ndarray,
                positives: Positives | None = None, frames: np.ndarray | None = None,
                matched: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(correct [Nq], has_positive [Nq])`` of the top-1 reference items ``best`` (-1: none; indices into the
    reference items at ``r_pos [Nr, P]``) of the query frames at ``q_pos [Nq, P]``, within ``radius``; ``frames
    [R_all, P]`` (every reference frame's position, a map's) or ``matched`` (explicit positives): a frame whose
    correct references are all frames without a window has one, and its answer is wrong (as the evaluation counts
    it: :func:`seqnet.metrics.recall.ground_truth`)."""
    truth = ground_truth(q_pos, r_pos, radius, positives, require=False, frames=frames, matched=matched)
    return truth.hits(best[:, None])[:, 0], truth.has_positive()


def summarize(est: Sequence[Estimate], correct: np.ndarray | None, has: np.ndarray | None,
              known: np.ndarray | None = None) -> dict[str, Any]:
    """Frames, answers, R@1 / AUC / R@100P over the full-window frames, and latency statistics (ms) in the steady
    state: the warm-up, every frame up to the first answered one (the first search allocates and warms its kernels:
    ~26 ms against a 2 ms median on a 200-frame map, hundreds of ms with large models), is left out of them and
    said apart (``warmup_frames``, ``warmup_max``). ``known [Nq]``: the frames whose truth is known (None: all);
    the others (a video's frames outside its track) are left out of every figure, counted as ``no_truth``: a
    frame whose place is unknown is neither right nor wrong (where a frame known to have no reference within the
    radius is a wrong answer when accepted)."""
    full = np.array([e.full_window for e in est], bool)
    lat = np.array([e.latency_ms for e in est])
    out: dict[str, Any] = {"frames": len(est), "answered": int(sum(e.ref_index >= 0 for e in est)),
                           "full_window": int(full.sum())}
    if correct is not None and has is not None:
        if known is not None:
            out["no_truth"] = int((full & ~known).sum())
            full = full & known
        pos = full & has
        conf = np.array([e.confidence for e in est])
        out.update(queries=int(pos.sum()), no_positive=int((full & ~has).sum()))
        if pos.any():  # else nothing to score: no R@1 (null in the JSON, never NaN)
            out.update({"recall@1": float(correct[pos].mean())},
                       **pr_summary(*precision_recall(conf[full], correct[full], has[full])[:2]))
    if len(lat):
        answered = np.flatnonzero([e.ref_index >= 0 for e in est])
        warm = int(answered[0]) + 1 if len(answered) and answered[0] + 1 < len(lat) else 0
        steady = lat[warm:]
        out["latency_ms"] = {"mean": float(steady.mean()), "median": float(np.median(steady)),
                             "p95": float(np.percentile(steady, 95)), "p99": float(np.percentile(steady, 99)),
                             "max": float(steady.max()), "warmup_frames": warm,
                             "warmup_max": float(lat[:warm].max()) if warm else 0.0}
    return out


def matrix_localizer(ds: Dataset, dist: np.ndarray, conf: LocalizeConfig) -> tuple[Localizer, np.ndarray]:
    """The localiser of ``conf`` over the distance matrix ``dist [Nq, Nr]`` of ``ds`` (the split taken), and
    the query frames as their row numbers ``[Nq, 1]``: replaying them streams the matrix row by row."""
    from ..reference.matrix import MatrixReference, frame_indices

    ref = MatrixReference(torch.as_tensor(np.ascontiguousarray(dist)), ds.reference, conf.windows({}), ds.name)
    return conf.localizer(ref, conf.radius or ds.radius), frame_indices(len(ds.query)).numpy()


def main(conf: LocalizeConfig, dataset: str | Path, out: str | Path, models: Sequence[str | Path] = (),
         shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None,
         distances: str | Path | None = None, similarity: bool = False, transposed: bool = False,
         calibration: tuple[float, str, float] | None = None, choose: Sequence[str] = ()) -> Written:
    """hloc-style stage: replay the query traverse of split ``conf.split`` of the dataset directory
    ``dataset`` against its reference traverse (or, with ``distances``, the rows of that ``[Nq, Nr]`` matrix file
    of the whole dataset, ``[Nr, Nq]`` when ``transposed``; ``similarity``: higher is closer); writes ``out``
    (track.csv) and
    its ``.json`` summary; returns ``out``. ``calibration``: ``(target precision, calibration split, risk)``: the
    calibration split is replayed first, a confidence threshold calibrated on it (:mod:`seqnet.metrics.calibration`)
    decides per frame (the track's ``accepted`` column), and the summary's ``calibrated`` says what it gave.
    ``choose``: the HVPR settings the user left free (``top_k``, ``fuse_top_k``, ``fuse_weight``), chosen on the val
    split first as ``seqnet eval --window causal`` chooses them (:func:`chosen_on_val`).
    The track is locked for the whole run (a second writer: exit 1)."""
    if distances is not None and (models or shortlist_model or rerank_model):
        raise ConfigError("--distances gives the frame distances: no model applies (methods on a matrix read "
                          "single-frame distances only)")
    with locked(check_output(out)):
        remove_dead_temps([Path(out), sidecar_of(Path(out))])
        return _main(conf, dataset, Path(out), models, shortlist_model, rerank_model, distances,
                     (similarity, transposed), calibration, choose)


def _localizer(conf: LocalizeConfig, ds: Dataset, full: Dataset, split: str, loaded: Mapping[str, SeqNet],
               distances: str | Path | None, reading: tuple[bool, bool]) -> tuple[Localizer, np.ndarray | None]:
    """The localiser of the split ``ds`` and the frames it replays in place of the query descriptors (None:
    those): over the reference traverse, or over the rows of the matrix."""
    if distances is None:
        return dataset_localizer(ds, loaded, conf), None
    from ..eval.matrix import orientation_check, read_matrix

    dist = read_matrix(distances, full, reading[0], split, reading[1])
    orientation_check(ds, dist, *reading)  # a reading the user probably meant is named (a warning), as eval does
    return matrix_localizer(ds, dist, conf)


def _main(conf: LocalizeConfig, dataset: str | Path, out: Path, models: Sequence[str | Path],
          shortlist_model: str | Path | None, rerank_model: str | Path | None, distances: str | Path | None,
          reading: tuple[bool, bool], calibration: tuple[float, str, float] | None = None,
          choose: Sequence[str] = ()) -> Written:
    from ..data.io import load_dataset
    from ..methods.checks import model_lengths
    from ..sequence.checkpoints import load_models, used_models

    full = load_dataset(dataset)
    split = default_split(conf.split, full.splits)
    used = used_models(conf.method, online_method(conf.method).models(), models, shortlist_model, rerank_model)
    if conf.seq_len is None and used.seq_len is not None:  # an unused S_L still gives L: the same windows
        conf = conf.merge(seq_len=used.seq_len)
    models, shortlist_model, rerank_model = used.paths, used.shortlist_model, used.rerank_model
    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    if calibration is not None:
        check_calibration_split(full, calibration[1], split)
    conf, selection = chosen_on_val(conf, full, split, loaded, choose if distances is None else (), dataset)
    ds = full.split(split)
    loc, est, correct, has = _replay_split(conf, ds, full, split, loaded, distances, reading)
    radius = conf.radius or ds.radius
    summary = summarize(est, correct, has)
    accept = None
    if calibration is not None:
        replayed = _replay_split(conf, full.split(calibration[1]), full, calibration[1], loaded, distances, reading)
        accept, summary["calibrated"] = _calibrated(replayed[1:3], (est, correct, has), *calibration)
    record = {"summary": summary, "config": {**conf.for_reference(loc.ref).to_dict(), "split": split,
                                             "seq_len": loc.seq_len,
                                             "match_len": loc.match_len, "radius": radius,
                                             "ground_truth": "explicit positives" if ds.positives is not None
                                             else "radius", "model_seq_len": model_lengths(loaded)},
              "inputs": {"dataset": str(Path(dataset).resolve()), **_matrix_inputs(distances, reading),
                         "models": [str(Path(p).resolve()) for p in (*models, shortlist_model, rerank_model) if p]},
              "provenance": {"reference": ds.reference.provenance, "query": ds.query.provenance,
                             "models": {r: m.provenance for r, m in loaded.items()}}}
    if selection:
        record["selection"] = selection
    warnings = _notices(conf, full, split, loaded, dataset, summary, calibration,
                        [(selection or {}).get(k) for k in ("warning", "leakage")])
    if warnings:
        record["warnings"] = warnings
    truth = _truth(ds, loc, est)
    record["truth"] = truth.record()
    write_track(check_output(out), track_rows(est, ds.query.names, ds.reference.names, correct, accept, truth),
                record)
    logger.debug("localize: %s", json.dumps(summary))
    return Written(out, record)


def chosen_on_val(conf: LocalizeConfig, full: Dataset, split: str, loaded: Mapping[str, SeqNet],
                  choose: Sequence[str], dataset: str | Path | None = None
                  ) -> tuple[LocalizeConfig, dict[str, Any] | None]:
    """``conf`` with the HVPR settings of ``choose`` chosen on the val split of ``full`` (the dataset directory
    ``dataset``) for replaying ``split``, as ``seqnet eval --window causal`` chooses them
    (:func:`seqnet.eval.select.choose_on_val`: never on test; nothing chosen on val itself, or without one), and
    what was chosen and why (None: nothing to say; the reasons are logged; a choice made on the models' training
    queries, or few val queries, is the selection's ``"leakage"`` / ``"warning"``, said with the run's other
    warnings). So the replay's R@1 is the one eval gives with the same settings."""
    from ..eval.config import EvalConfig
    from ..eval.select import choose_on_val

    m = online_method(conf.method)
    choose = [c for c in choose if c in (("fuse_top_k", "fuse_weight") if m.fused else ("top_k",))]
    if not choose or m.kind != "hvpr":  # nothing of this method's left to choose (given, e.g. --top-k): nothing said
        return conf, None
    econf = EvalConfig(methods=(conf.method,), seq_len=conf.seq_len, match_len=conf.match_len, window="causal",
                       radius=conf.radius, top_k=conf.top_k or TOP_K, fuse_weight=conf.fuse_weight,
                       fuse_top_k=conf.fuse_top_k, device=conf.device, allow_mismatch=conf.allow_mismatch)
    _, found = choose_on_val(full, split, loaded, econf, choose, dataset)
    if found is None:
        return conf, None
    selection = found["selection"]
    for choice in selection.get("hvpr", []):
        conf = conf.merge(**choice["settings"])  # of SELECTABLE: top_k, fuse_top_k, fuse_weight
        logger.info("%s", shown(choice["reason"]))
    if selection.get("not_chosen"):
        logger.warning("%s", shown(selection["not_chosen"]))
    return conf, selection


def _truth(ds: Dataset, loc: Localizer, est: Sequence[Estimate]) -> FrameTruth:
    """Each replayed frame's position and the error of its estimate (:class:`FrameTruth`; a dataset's traverses
    always hold positions)."""
    best = np.array([e.ref_index for e in est], dtype=np.int64)
    return FrameTruth.of(ds.query.positions, ds.reference.positions[loc.ref_items], best, ds.position_unit)


def _notices(conf: LocalizeConfig, full: Dataset, split: str, loaded: Mapping[str, SeqNet], dataset: str | Path,
             summary: Mapping[str, Any], calibration: tuple[float, str, float] | None,
             chosen: Sequence[str | None] = ()) -> list[str]:
    """What eval says beside the same R@1 (``eval --window causal``), said as warnings: no split named test,
    training or epoch-selection queries among the replayed ones (:func:`seqnet.eval.notices.scored_notices`), what
    the choice of HVPR settings on val warned of (``chosen``: few val queries, training queries), and an R@1 over
    few frames (:func:`seqnet.eval.notices.few_queries`)."""
    from ..eval.notices import few_queries, say, scored_notices

    lines: list[str | None] = [*scored_notices(conf.split, full, split, loaded, dataset,
                                               calibration[1] if calibration is not None else None), *chosen]
    if "recall@1" in summary:  # absent when no replayed frame has a true match
        lines.append(few_queries({conf.method: (summary["queries"], summary["recall@1"])}))
    return say(lines)


def _replay_split(conf: LocalizeConfig, ds: Dataset, full: Dataset, split: str, loaded: Mapping[str, SeqNet],
                  distances: str | Path | None,
                  reading: tuple[bool, bool]) -> tuple[Localizer, list[Estimate], np.ndarray, np.ndarray]:
    """The split ``ds`` replayed: its localiser, estimates and ``(correct [Nq], has_positive [Nq])`` of their
    top-1."""
    loc, frames = _localizer(conf, ds, full, split, loaded, distances, reading)
    est = replay_query(loc, ds, frames)
    best = np.array([e.ref_index for e in est], dtype=np.int64)
    return (loc, est, *track_truth(ds, loc.ref_items, conf.radius or ds.radius, best))


def _calibrated(cal_run: tuple[list[Estimate], np.ndarray], run: tuple[list[Estimate], np.ndarray, np.ndarray],
                target: float, cal_split: str, risk: float) -> tuple[np.ndarray, dict[str, Any]]:
    """``(accepted [Nq], what it gave)``: a threshold calibrated on the full-window frames of the calibration
    replay ``cal_run`` (estimates, correct), applied to the replay ``run`` (estimates, correct, has_positive); a
    frame without a full window is never accepted."""
    def arrays(est: list[Estimate]) -> tuple[np.ndarray, np.ndarray]:
        return np.array([e.confidence for e in est]), np.array([e.full_window for e in est], bool)

    conf_c, full_c = arrays(cal_run[0])
    cal = calibrate(conf_c[full_c], cal_run[1][full_c], target, risk)
    (conf_q, full_q), correct, has = arrays(run[0]), run[1], run[2]
    out = apply_threshold(cal, conf_q[full_q], correct[full_q], has[full_q])
    out["calibration"]["split"] = cal_split
    return accepted(cal, conf_q) & full_q, out


def _matrix_inputs(distances: str | Path | None, reading: tuple[bool, bool]) -> dict[str, Any]:
    """The matrix file, its reading (``(similarity, transposed)``) and digest, for the summary's inputs."""
    if distances is None:
        return {}
    return {"distances": str(Path(distances).resolve()), "similarity": bool(reading[0]),
            "transposed": bool(reading[1]), "distances_digest": file_digest(distances)}
