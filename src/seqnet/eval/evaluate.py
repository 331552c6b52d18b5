"""Evaluation: run methods on a dataset and report Recall@K with per-stage timing.

A sequence method's queries are the frames whose windows (L frames for sequence descriptors, L_m for
the sequence matchers) fit inside their sequence, and its references the reference frames whose
windows fit; a single-frame method (``single``, ``s1``) needs no window: it queries and indexes every
frame (``common_queries``: every method on the sequence methods' items, one query set). Each
method's entry reports its queries and the number left out (no full window, and why; no reference
within the radius). See :mod:`seqnet.eval.evaluation`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.stage import Written
from ..data.resample import kept_indices, resample_dataset
from ..data.traverse import Dataset, Traverse, default_split
from ..methods.checks import check_inputs, model_lengths
from ..methods.grammar import Method, parse_method
from ..methods.route import route_warnings
from ..metrics.recall import GroundTruth, ground_truth
from ..reference.plain import PlainReference, runs_plain
from ..reference.traverse import TraverseReference
from ..report.guidance import learned_below_baseline, model_entries, note_entries
from ..security.text import shown
from ..sequence.described import Described
from ..sequence.npdescribed import PlainDescribed
from ..sequence.windows import Windows
from .calibrated import add_calibration, calibration_failed, calibration_on_test, check_calibration_split
from .config import EvalConfig
from .evaluation import Evaluation, merge, method_windows
from .notices import (
    add_warnings,
    default_ks_note,
    leakages,
    radius_ignored,
    selection_leakage,
    shift_notice,
    split_note,
    trivial_ks,
)
from .notices.chance import chance_notice
from .outputs import EvalOutputs
from .runner import run

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

# (dataset, evaluated split, loaded models, settings) -> (settings, entries added to the results)
Prepare = Callable[[Dataset, str, "Mapping[str, SeqNet]", EvalConfig], "tuple[EvalConfig, Mapping[str, Any] | None]"]


def check_types(ds: Dataset, conf: EvalConfig, models: Mapping[str, SeqNet] | None) -> None:
    """The arguments of :func:`evaluate` are what they should be (a clear error instead of an AttributeError)."""
    if not isinstance(ds, Dataset):
        raise ConfigError(f"evaluate() needs a seqnet Dataset, got {type(ds).__name__} (hint: load_dataset(DIR))")
    if not isinstance(conf, EvalConfig):
        raise ConfigError(f"evaluate() needs an EvalConfig, got {type(conf).__name__} {conf!r:.60} "
                          "(hint: EvalConfig(methods=('single',)) or EvalConfig.from_dict({...}))")
    if models:  # the model class loads torch: only when there are models to check
        from ..sequence.model import SeqNet

        if not isinstance(models, Mapping) or not all(isinstance(m, SeqNet) for m in models.values()):
            raise ConfigError("models must map a role ('seqnet' for S_L, 's1' for S_1) to a SeqNet model")
    unknown = set(models or {}) - {"seqnet", "s1"}
    if unknown:
        raise ConfigError(f"unknown model role(s) {sorted(unknown)}; valid: seqnet (S_L), s1 (S_1)")


def _entry(m: Method, conf: EvalConfig, models: Mapping[str, SeqNet]) -> dict[str, Any]:
    """What a method resolved to: kind, shortlister, re-ranker, lengths, K, models."""
    info = m.summary()
    info["seq_len"] = conf.windows.seq_len
    if m.rerank:
        info["match_len"] = conf.windows.match_len
    if m.kind == "hvpr":
        info["top_k"] = conf.shortlist_size(m)
    if m.fused:
        info["fuse_weight"] = conf.weight(m)
    info["models"] = model_entries({r: models[r] for r in sorted(m.models())})
    return info


def evaluate(ds: Dataset, conf: EvalConfig | None = None, models: Mapping[str, SeqNet] | None = None) -> Evaluation:
    """Evaluate methods on ``ds`` (already restricted to the split to evaluate).

    Args:
        ds: dataset (reference + query traverses, radius).
        conf: settings (default :class:`EvalConfig`).
        models: trained models by role: ``{"seqnet": S_L, "s1": S_1}`` (optional).

    Returns:
        :class:`Evaluation` whose ``results`` follow the ``--json`` schema.
    """
    conf = EvalConfig() if conf is None else conf
    check_types(ds, conf, models)
    keep = kept_indices(ds, conf.resample_every, conf.resample_side) if conf.resample_every else None
    ds = resample_dataset(ds, conf.resample_every, conf.resample_side)
    models = dict(models or {})
    conf = conf.resolve(models, ds.radius)
    methods = [parse_method(n) for n in conf.methods]
    groups = method_windows(methods, conf.windows, conf.common_queries)
    check_inputs(ds, methods, models, conf.windows.seq_len, conf.windows.match_len, conf.allow_mismatch,
                 max(w.longest for w in groups))
    plain = runs_plain(methods, models, conf.backend, conf.device)  # numpy, no torch: reference.plain
    dev = "cpu" if plain else get_device(conf.device)
    for model in models.values():
        model.to(dev).eval()
        with torch.no_grad():  # its first call allocates: not charged to the first method that uses it
            model(torch.zeros((1, model.seq_len, model.in_dims), device=dev))
    parts = [_evaluate_group(ds, ms, w, conf, models, dev, plain) for w, ms in groups.items()]
    out = merge(parts, conf.methods)
    out.results["config"] = {**conf.to_dict(), "dataset": ds.name, "device": str(dev),
                             "ground_truth": "explicit positives" if ds.positives is not None else "radius",
                             "models": model_entries(models),
                             "model_seq_len": model_lengths(models)}
    out.dataset, out.frame_names = ds, (ds.query.names, ds.reference.names)
    out.frame_numbers = (keep["query"], keep["reference"]) if keep else (None, None)
    return out


def _evaluate_group(ds: Dataset, methods: list[Method], windows: Windows, conf: EvalConfig,
                    models: Mapping[str, SeqNet], dev: Any, plain: bool = False) -> Evaluation:
    """The methods that share ``windows``, on those windows' query and reference items (``plain``: in numpy)."""
    query = (PlainDescribed(ds.query.descriptors, ds.query.seq_bounds, windows, "query") if plain
             else Described(ds.query.descriptors, ds.query.seq_bounds, windows, models, dev, "query"))
    ref = (PlainReference(ds.reference, windows, ds.name) if plain
           else TraverseReference(ds.reference, windows, models, dev, conf.backend, ds.name))
    truth = dataset_truth(ds, query.side.items, ref.items, conf.radius)
    out = run(methods, query, ref, truth, conf, len(ds.query), lambda m: _entry(m, conf, models), windows=windows,
              with_torch=not plain)
    out.query_names, out.reference_names = item_names(ds.query, query.side.items), item_names(ds.reference, ref.items)
    return out


def dataset_truth(ds: Dataset, q_items: np.ndarray, r_items: np.ndarray, radius: float) -> GroundTruth:
    """What is correct for the query items ``q_items`` among the reference items ``r_items`` of ``ds``: its
    explicit positives, else the radius."""
    positives = ds.positives.select(q_items, r_items) if ds.positives is not None else None
    return ground_truth(ds.query.positions[q_items], ds.reference.positions[r_items], radius, positives, ds.name,
                        ds.position_unit)


def item_names(t: Traverse, items: np.ndarray) -> list[str] | None:
    """The image names of the frames ``items`` of ``t`` (None when it has none)."""
    return [t.names[i] for i in items] if t.names else None


def one_retrieved(ev: Evaluation) -> str | None:
    """What to say when some methods retrieved one reference per query (``--ks 1``): their confidence cannot
    compare the top-1 with another place, so their PR entries are empty."""
    names = [n for n, r in ev.retrieved.items() if r.shape[1] < 2]
    if not names:
        return None
    return (f"{', '.join(names)} retrieved one reference per query (the largest K of --ks is 1): the confidence "
            "compares the top-1 with the best other place retrieved, so no PR curve, AUC, R@100P or "
            "confidence_for_precision is given for them; add a larger K (e.g. --ks 1,20)")


def video_clock_note(ev: Evaluation) -> str | None:
    """A ``dataset from-video`` query track a constant time off the reference's, seen in the top-1 answers of a
    method (the first that shows it: :func:`seqnet.sources.tracks.offset.dataset_offset_note`); else None."""
    from ..sources.tracks.offset import dataset_offset_note

    notes = (dataset_offset_note(ev.dataset, ev.view(n).q_items, ev.view(n).r_items, r[:, 0])
             for n, r in ev.retrieved.items() if r.ndim == 2 and r.shape[1])
    return next((note for note in notes if note), None)


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
        conf = conf.replace(seq_len=used.seq_len)
    return conf, (used.paths, used.shortlist_model, used.rerank_model)


def _evaluate_dir(conf: EvalConfig, dataset: str | Path, models: Sequence[str | Path],
                  shortlist_model: str | Path | None, rerank_model: str | Path | None,
                  prepare: Prepare | None = None) -> Evaluation:
    from ..data.io import load_dataset
    from ..data.sanity.truth import transposed_positives
    from ..sequence.checkpoints import load_models

    ds = load_dataset(dataset)
    split = default_split(conf.split, ds.splits)
    evaluated = ds.split(split)  # an unknown split fails before any work
    conf, (models, shortlist_model, rerank_model) = _used(conf, models, shortlist_model, rerank_model)
    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    conf, prepared = prepare(ds, split, loaded, conf) if prepare is not None else (conf, None)
    cal = None
    if conf.target_precision is not None:  # first: a calibration split that cannot serve fails before any work
        if max(conf.ks) < 2:
            raise ConfigError(f"--target-precision needs a K of 2 or more in --ks (got {max(conf.ks)}): the "
                              "confidence compares the top-1 with the best other place retrieved; e.g. --ks 1,20")
        check_calibration_split(ds, conf.calibrate_split, split)
        try:
            cal = evaluate(ds.split(conf.calibrate_split), conf.replace(split=conf.calibrate_split), loaded)
        except ConfigError as e:
            raise calibration_failed(ds, conf.calibrate_split, e) from e
    ev = evaluate(evaluated, conf.replace(split=split), loaded)
    if cal is not None:
        add_calibration(ev, cal, conf.target_precision, conf.risk, conf.calibrate_split)
    ev.results.update(prepared or {})
    ev.results["config"]["dataset_path"] = str(dataset)
    ev.results["config"]["query_range"] = list(ds.ranges(split)["query"])  # per-query numbering (VME)
    chosen = [(prepared or {}).get("selection", {}).get(k) for k in ("warning", "leakage")]  # said once it succeeded
    flipped = transposed_positives(ds)  # the whole dataset's square positives; said instead of a shift
    add_warnings(ev, [split_note(conf.split, list(ds.splits), len(evaluated.query)), *chosen,
                      *route_warnings(ev.dataset, ev.truth, ev.q_items, ev.results["methods"]), one_retrieved(ev),
                      flipped or shift_notice(ev) or chance_notice(ev, conf.ks),
                      radius_ignored(conf.radius, ds.positives is not None),
                      trivial_ks(ev, conf.ks), video_clock_note(ev),
                      calibration_on_test(ds, conf.calibrate_split if cal else None, split),
                      *selection_leakage(loaded, dataset, ds, split, conf.query_every)])
    leaks = leakages(loaded, dataset, ds, split, conf)
    if leaks:
        ev.results["leakage"] = leaks
        for line in leaks:
            logger.warning("%s", shown(line))  # it names checkpoints' records: text from files
    ev.results["learned_below_baseline"] = note_entries(learned_below_baseline(ev.results))
    if (trivial := default_ks_note(ev, conf.ks)) is not None:
        ev.results["trivial_ks"] = trivial  # a note after the table (cli), not a warning
    ev.results["inputs"] = {"dataset": str(Path(dataset).resolve()),
                            "models": [str(Path(p).resolve()) for p in (*models, shortlist_model, rerank_model) if p]}
    return ev
