"""Evaluation: what ``seqnet eval`` does, minus the files (:func:`evaluate`, the Python API), and the stage that
reads a dataset directory and checkpoints and writes the outputs (:func:`main`: load, :func:`evaluate`, write).

:func:`evaluate` takes the split ``conf.split`` of the dataset (test when it defines one, else all of it), calibrates
a confidence threshold on ``conf.calibrate_split`` when ``conf.target_precision`` is set
(:mod:`seqnet.eval.calibrated`), scores the methods (:func:`seqnet.eval.score.score`: which queries each method
evaluates, and why some are left out) and says what the data suggest the user meant instead (one
``logger.warning`` line each, kept in ``results["warnings"]``; a model scored on its own training queries in
``results["leakage"]``; learned methods below their model-free counterpart in ``results["learned_below_baseline"]``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..core.stage import Written
from ..data.traverse import Dataset, Traverse, default_split
from ..methods.grammar import parse_method
from ..methods.route import route_warnings
from ..report.guidance import format_notes, learned_below_baseline, note_entries
from ..security.text import shown
from .calibrated import add_calibration, calibration_failed, calibration_on_test, check_calibration_split
from .config import EvalConfig
from .evaluation import Evaluation
from .notices import (
    add_warnings,
    default_ks_note,
    leakages,
    one_retrieved,
    radius_ignored,
    selection_leakage,
    shift_notice,
    split_note,
    trivial_ks,
    video_clock_note,
)
from .notices.chance import chance_notice
from .notices.unreduced import unreduced_counterparts
from .outputs import EvalOutputs
from .score import check_types, score

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

# (dataset, evaluated split, loaded models, settings) -> (settings, entries added to the results)
Prepare = Callable[[Dataset, str, "Mapping[str, SeqNet]", EvalConfig], "tuple[EvalConfig, Mapping[str, Any] | None]"]


def evaluate(ds: Dataset, conf: EvalConfig | None = None, models: Mapping[str, SeqNet] | None = None, *,
             source: str | Path | None = None, prepare: Prepare | None = None) -> Evaluation:
    """What ``seqnet eval`` does for ``ds``, ``conf`` and ``models``, minus writing files: the split ``conf.split``
    of ``ds`` (None: test when ``ds`` defines it, said in one warning naming how to score every query, else all;
    a split of a dataset, ``ds.split("test")``, is evaluated whole as that split of the dataset it was taken
    from: the same query numbering and leakage checks; a split it does not hold is refused), a threshold
    calibrated on ``conf.calibrate_split`` with ``conf.target_precision``, and the warnings and notes of
    ``seqnet eval`` (logged, and kept in the results; the notes the CLI prints under its table, learned methods
    below their model-free counterpart, are logged as warnings too).

    Args:
        ds: dataset (reference + query traverses, radius, splits).
        conf: settings (default :class:`EvalConfig`); ``results["config"]["split"]`` is the split evaluated.
        models: trained models by role: ``{"seqnet": S_L, "s1": S_1}`` (optional).
        source: the dataset directory ``ds`` was loaded from (``seqnet eval --dataset``; default: the one
            :func:`seqnet.load_dataset` read it from, ``ds.path``, or its source's for a split): the leakage checks
            then also compare the file hashes and path a checkpoint recorded, and a ``--pca`` reduction's learned
            methods are compared with the model-free ones on the unreduced dataset beside it; without it, a model's
            training and epoch-selection queries are found by its recorded provenance and query names (a split
            whose source is unknown is said).
        prepare: ``prepare(ds, split, models, conf)`` -> ``(conf, entries)``, called first, may change the settings
            and add entries to the results (:func:`seqnet.eval.select.main`: the HVPR settings chosen on val).

    Returns:
        :class:`Evaluation` whose ``results`` follow the ``--json`` schema.
    """
    conf = EvalConfig() if conf is None else conf
    check_types(ds, conf, models)
    whole, split = split_source(ds, conf.split)
    said = None
    if whole is ds:
        evaluated = split_of(ds, split)  # an unknown split fails before any work
        if conf.split is None and split != "all":
            a, b = ds.ranges(split)["query"]
            said = (f"evaluate(): dataset {ds.name!r} has splits and no split was given: scoring its {split} split "
                    f"only (queries {a}:{b}, {b - a} of {len(ds.query)}), as seqnet eval does; hint: "
                    "EvalConfig(split='all') scores every query")
    else:
        evaluated, conf = ds, conf.merge(split=split)
    source = source if source is not None else whole.path  # load_dataset's directory: what seqnet eval is given
    ev = evaluate_split(whole, split, evaluated, conf, models, source, prepare, said)
    for line in after_table(ev.results):
        logger.warning("%s", shown(line))
    return ev


def after_table(results: Mapping[str, Any]) -> list[str]:
    """What ``seqnet eval`` prints after its table and :func:`evaluate` logs instead (the CLI calls
    :func:`evaluate_split`): the learned-below-baseline notes, and each method whose calibrated threshold abstains
    on every query, with why."""
    lines = format_notes(learned_below_baseline(results))
    for name, r in results.get("methods", {}).items():
        cal = (r.get("calibrated") or {}).get("calibration") or {}
        if cal and cal.get("threshold") is None:
            lines.append(f"evaluate(): {name} abstains on every query at target precision "
                         f"{results['config'].get('target_precision')} ({cal.get('reason')})")
    return lines


def split_source(ds: Dataset, split: str | None) -> tuple[Dataset, str]:
    """``(whole, split)``: the dataset ``ds`` was split from and the split's name when ``ds`` is an unchanged
    ``whole.split(name)`` (its frames, descriptors, radius and positives still that split's) and no other split
    is asked (None, ``all`` or that name); else ``ds`` and ``split`` (None: test when ``ds`` defines it, else
    all)."""
    if ds.source is None or split not in (None, "all", ds.source[1]):
        return ds, default_split(split, ds.splits)
    whole, name = ds.source
    rng = whole.ranges(name)
    same = rng is not None and ds.radius == whole.radius and all(
        same_frames(getattr(ds, side), getattr(whole, side), rng[side]) for side in ("query", "reference"))
    same = same and same_positives(ds, whole, rng)
    return (whole, name) if same else (ds, default_split(None if split == name else split, ds.splits))


def same_frames(part: Traverse, whole: Traverse, rng: tuple[int, int]) -> bool:
    """Whether ``part`` holds frames ``rng`` of ``whole``: the same positions, names and descriptors (the same
    memory, as :meth:`Traverse.subset` leaves them, else equal values)."""
    a, b = rng
    d, w = part.descriptors, whole.descriptors[a:b]
    if len(part) != b - a or not np.array_equal(part.positions, whole.positions[a:b]):
        return False
    if part.names != (None if whole.names is None else whole.names[a:b]):
        return False
    if d.shape != w.shape or d.dtype != w.dtype:
        return False
    same_memory = d.__array_interface__["data"][0] == w.__array_interface__["data"][0] and d.strides == w.strides
    return d is w or same_memory or bool(np.array_equal(d, w))


def same_positives(ds: Dataset, whole: Dataset, rng: Mapping[str, tuple[int, int]]) -> bool:
    """Whether ``ds``'s explicit positives (or their absence) are those of the split ``rng`` of ``whole``."""
    if ds.positives is None or whole.positives is None:
        return ds.positives is None and whole.positives is None
    mine = whole.positives.select(np.arange(*rng["query"]), np.arange(*rng["reference"]))
    return bool(np.array_equal(mine.indptr, ds.positives.indptr) and np.array_equal(mine.indices, ds.positives.indices))


def evaluate_split(ds: Dataset, split: str, evaluated: Dataset, conf: EvalConfig,
                   models: Mapping[str, SeqNet] | None, source: str | Path | None = None,
                   prepare: Prepare | None = None, said: str | None = None) -> Evaluation:
    """:func:`evaluate` of the split ``split`` of ``ds``, already taken (``evaluated``: ``ds.split(split)``), with
    the warnings of ``seqnet eval`` (and ``said``, the caller's, first); the notes after the table are left to
    the caller (the CLI prints them)."""
    models = dict(models or {})
    conf, prepared = prepare(ds, split, models, conf) if prepare is not None else (conf, None)
    cal = calibration(ds, split, conf, models)  # first: a calibration split that cannot serve fails before any work
    ev = score(evaluated, conf.merge(split=split), models)
    if cal is not None:
        add_calibration(ev, cal, conf.target_precision, conf.risk, conf.calibrate_split)
    ev.results.update(prepared or {})
    add_warnings(ev, [said])
    rng = ds.ranges(split)  # per-query numbering (VME, --per-query): rows of the dataset's whole lists
    ev.results["config"].update(query_range=list(rng["query"]), reference_range=list(rng["reference"]))
    if source is not None:
        ev.results["config"]["dataset_path"] = str(source)
    if models and any(getattr(m, "trained_on", None) for m in models.values()) and unknown_split(ds):
        add_warnings(ev, [f"evaluate(): dataset {ds.name!r} is a split whose source is not known here (saved and "
                          "loaded again, changed, or a split of a split): whether the models were trained on its "
                          "queries cannot be checked; hint: evaluate the whole dataset with EvalConfig(split=NAME)"])
    say_notices(ev, ds, split, conf, models, source, prepared, calibrated=cal is not None)
    return ev


def unknown_split(ds: Dataset) -> bool:
    """Whether ``ds`` looks like a split of a dataset (``name[split]``, no splits of its own) that is evaluated
    without the dataset it was taken from (:func:`split_source`): query numbers and names are not the ones a
    checkpoint recorded."""
    return not ds.splits and ds.name.endswith("]") and "[" in ds.name


def split_of(ds: Dataset, split: str) -> Dataset:
    """The split ``split`` of ``ds`` (a name it defines, ``all`` or a range ``A:B``); a name given to a dataset that
    defines no splits (one already split, or built without) is refused with a hint."""
    if not ds.splits and split != "all" and ds.ranges(split) is None:
        raise ConfigError(f"split {split!r}: dataset {ds.name!r} defines no splits (a split of a dataset has none); "
                          f"hint: evaluate the whole dataset (load_dataset(DIR)) with split={split!r}, or this one "
                          "without a split")
    return ds.split(split)


def calibration(ds: Dataset, split: str, conf: EvalConfig, models: Mapping[str, SeqNet]) -> Evaluation | None:
    """The evaluation of ``conf.calibrate_split`` a threshold is calibrated on (``conf.target_precision``; None
    without one), after checking that it can serve: a K of 2 or more, a split apart from the evaluated ``split``."""
    if conf.target_precision is None:
        return None
    if max(conf.ks) < 2:
        raise ConfigError(f"--target-precision needs a K of 2 or more in --ks (got {max(conf.ks)}): the "
                          "confidence compares the top-1 with the best other place retrieved; e.g. --ks 1,20 "
                          "(EvalConfig(ks=(1, 20)) in Python)")
    check_calibration_split(ds, conf.calibrate_split, split)
    try:
        return score(ds.split(conf.calibrate_split), conf.merge(split=conf.calibrate_split), models)
    except ConfigError as e:
        raise calibration_failed(ds, conf.calibrate_split, e) from e


def say_notices(ev: Evaluation, ds: Dataset, split: str, conf: EvalConfig, models: Mapping[str, SeqNet],
                source: str | Path | None, prepared: Mapping[str, Any] | None, calibrated: bool) -> None:
    """Log ``seqnet eval``'s warnings on the evaluation ``ev`` of ``split`` of ``ds`` and keep them in its results:
    ``warnings`` (the data, the settings, the val choice of ``prepared``), ``leakage`` (models scored on their own
    training queries), ``learned_below_baseline`` and ``trivial_ks`` (notes after the table)."""
    from ..data.sanity.truth import transposed_positives

    dataset: Any = source  # None: the checkpoints' records are held to provenance and query names only
    chosen = [(prepared or {}).get("selection", {}).get(k) for k in ("warning", "leakage")]  # said once it succeeded
    flipped = transposed_positives(ds)  # the whole dataset's square positives; said instead of a shift
    a, b = ds.ranges(split)["query"]
    add_warnings(ev, [split_note(conf.split, list(ds.splits), b - a), *chosen,
                      *route_warnings(ev.dataset, ev.truth, ev.q_items, ev.results["methods"]), one_retrieved(ev),
                      flipped or shift_notice(ev) or chance_notice(ev, conf.ks),
                      radius_ignored(conf.radius, ds.positives is not None),
                      trivial_ks(ev, conf.ks), video_clock_note(ev),
                      calibration_on_test(ds, conf.calibrate_split if calibrated else None, split),
                      *selection_leakage(models, dataset, ds, split, conf.query_every)])
    evaluated, calibration = leakages(models, dataset, ds, split, conf)
    leaks = [*evaluated, *calibration]
    if leaks:
        ev.results["leakage"] = leaks
        ev.results["config"]["calibrated_on_training_queries"] = bool(calibration)  # the below-target note names it
        for line in leaks:
            logger.warning("%s", shown(line))  # it names checkpoints' records: text from files
    unreduced_counterparts(ev, ds, split, conf, source)  # a --pca dataset: the counterparts on its unreduced one
    ev.results["learned_below_baseline"] = note_entries(learned_below_baseline(ev.results))
    if (trivial := default_ks_note(ev, conf.ks)) is not None:
        ev.results["trivial_ks"] = trivial  # a note after the table (cli), not a warning


def main(conf: EvalConfig, dataset: str | Path, out: str | Path | None, models: Sequence[str | Path] = (),
         shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None,
         per_query: str | Path | None = None, report: Any = None, figures: bool = False, overwrite: bool = False,
         json: str | Path | None = None, extra: Mapping[str, Any] | None = None,
         prepare: Prepare | None = None) -> Written:
    """hloc-style stage: evaluate ``conf.split`` of the dataset directory ``dataset`` with the model
    checkpoints given (``extra``: entries added to the results); writes ``out/results.json`` (results,
    resolved config, inputs), with ``figures``
    ``out/pr_curve.png``, with ``report`` (a :class:`seqnet.report.html.ReportConfig`) ``out/report.html``,
    with ``per_query`` one row per method and query (``.csv`` or ``.jsonl``, ...), with ``json`` a copy of
    the results: :class:`seqnet.eval.outputs.EvalOutputs` (``out`` None: no folder); returns the results
    path and the results. ``prepare(dataset, split, models, conf)``, called once both are loaded, may change the
    settings and add entries to the results (:func:`seqnet.eval.select.main`: the HVPR settings chosen on val)."""
    outputs = EvalOutputs(out, per_query, json, figures, report, overwrite)
    with outputs.session(conf.methods):  # a second evaluation into the same folder is refused (exit 1)
        ev = _evaluate_dir(conf, dataset, models, shortlist_model, rerank_model, prepare)
        ev.results.update(extra or {})
        return outputs.write(ev)


def _used(conf: EvalConfig, models: Sequence[str | Path], shortlist_model: str | Path | None,
          rerank_model: str | Path | None) -> tuple[EvalConfig, tuple[Sequence[str | Path], Any, Any]]:
    """``conf`` and the checkpoints its methods use (:func:`seqnet.sequence.checkpoints.used_models`): a model no
    method uses is not loaded; an unused S_L still gives L (the same windows). Methods None: every model given
    (the defaults are those the models allow)."""
    from ..sequence.checkpoints import used_models

    if conf.methods is None:
        return conf, (models, shortlist_model, rerank_model)
    used = used_models(", ".join(conf.methods), set().union(*(parse_method(m).models() for m in conf.methods)),
                       models, shortlist_model, rerank_model)
    if conf.seq_len is None and used.seq_len is not None:
        conf = conf.merge(seq_len=used.seq_len)
    return conf, (used.paths, used.shortlist_model, used.rerank_model)


def _evaluate_dir(conf: EvalConfig, dataset: str | Path, models: Sequence[str | Path],
                  shortlist_model: str | Path | None, rerank_model: str | Path | None,
                  prepare: Prepare | None = None) -> Evaluation:
    """:func:`evaluate` of the dataset directory ``dataset`` with the checkpoints its methods use (``inputs``: the
    paths read)."""
    from ..data.io import load_dataset
    from ..sequence.checkpoints import load_models

    ds = load_dataset(dataset)
    split = default_split(conf.split, ds.splits)
    evaluated = split_of(ds, split)  # taken once; an unknown split fails before any model is loaded
    conf, (models, shortlist_model, rerank_model) = _used(conf, models, shortlist_model, rerank_model)
    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    ev = evaluate_split(ds, split, evaluated, conf, loaded, source=dataset, prepare=prepare)
    ev.results["inputs"] = {"dataset": str(Path(dataset).resolve()),
                            "models": [str(Path(p).resolve()) for p in (*models, shortlist_model, rerank_model) if p]}
    return ev
