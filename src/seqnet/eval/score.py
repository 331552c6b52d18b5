"""Scoring one dataset as given (:func:`score`): every method ranked and scored on its items, no split chosen and
nothing said beside the numbers (:func:`seqnet.eval.evaluate.evaluate` does both, around this).

A sequence method's queries are the frames whose windows (L frames for sequence descriptors, L_m for
the sequence matchers) fit inside their sequence, and its references the reference frames whose
windows fit; a single-frame method (``single``, ``s1``) needs no window: it queries and indexes every
frame (``common_queries``: every method on the sequence methods' items, one query set). Each
method's entry reports its queries and the number left out (no full window, and why; no reference
within the radius). See :mod:`seqnet.eval.evaluation`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..data.resample import kept_indices, resample_dataset
from ..data.traverse import Dataset, Traverse
from ..methods.checks import check_inputs, model_lengths
from ..methods.grammar import Method, parse_method
from ..methods.trained import holds_training_data
from ..metrics.recall import GroundTruth, ground_truth
from ..reference.plain import PlainReference, runs_plain
from ..reference.traverse import TraverseReference
from ..report.guidance import model_entries
from ..sequence.described import Described
from ..sequence.npdescribed import PlainDescribed
from ..sequence.windows import Windows
from .config import EvalConfig
from .evaluation import Evaluation, descriptor_record, merge, method_windows
from .runner import run

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


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


def _entry(m: Method, conf: EvalConfig, entries: Mapping[str, dict[str, Any]]) -> dict[str, Any]:
    """What a method resolved to: kind, shortlister, re-ranker, lengths, K, models (of ``entries``: every
    model's :func:`~seqnet.report.guidance.model_entries`, made once)."""
    info = m.summary()
    info["seq_len"] = conf.windows.seq_len
    if m.rerank:
        info["match_len"] = conf.windows.match_len
    if m.kind == "hvpr":
        info["top_k"] = conf.shortlist_size(m)
    if m.fused:
        info["fuse_weight"] = conf.weight(m)
    info["models"] = {r: dict(entries[r]) for r in sorted(m.models())}
    return info


def score(ds: Dataset, conf: EvalConfig | None = None, models: Mapping[str, SeqNet] | None = None) -> Evaluation:
    """Score the methods of ``conf`` on the whole of ``ds``, as given (``conf.split``, ``target_precision`` and
    the notices are :func:`seqnet.eval.evaluate.evaluate`'s: this is its scoring step, and what a stage that
    evaluates a split many times calls, e.g. training's validation).

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
    entries = trained_elsewhere(model_entries(models), models, ds)  # once: it reads each checkpoint's record
    parts = [_evaluate_group(ds, ms, w, conf, models, dev, plain, entries) for w, ms in groups.items()]
    out = merge(parts, conf.methods)
    out.results["config"] = {**conf.to_dict(), "dataset": ds.name, "device": str(dev),
                             "ground_truth": "explicit positives" if ds.positives is not None else "radius",
                             "models": entries,
                             "model_seq_len": model_lengths(models)}
    out.results["descriptors"] = descriptor_record(ds)
    out.dataset, out.frame_names = ds, (ds.query.names, ds.reference.names)
    out.frame_numbers = (keep["query"], keep["reference"]) if keep else (None, None)
    return out


def trained_elsewhere(entries: dict[str, dict[str, Any]], models: Mapping[str, SeqNet],
                      ds: Dataset) -> dict[str, dict[str, Any]]:
    """``entries`` with ``"trained_on_dataset"`` (the path its checkpoint records) for each model trained on
    another dataset than ``ds``'s, read from a folder (not the same descriptors:
    :func:`~seqnet.methods.trained.holds_training_data`; unknown: nothing added); the learned-below-baseline notes
    name it as a likely cause."""
    whole = ds.source[0] if ds.source is not None else ds
    if whole.path is None:
        return entries
    for role, model in models.items():
        t = getattr(model, "trained_on", None)
        if isinstance(t, Mapping) and isinstance(t.get("dataset"), str) and role in entries \
                and not holds_training_data(model, whole.path, whole):
            entries[role]["trained_on_dataset"] = t["dataset"]
    return entries


def _evaluate_group(ds: Dataset, methods: list[Method], windows: Windows, conf: EvalConfig,
                    models: Mapping[str, SeqNet], dev: Any, plain: bool,
                    entries: Mapping[str, dict[str, Any]]) -> Evaluation:
    """The methods that share ``windows``, on those windows' query and reference items (``plain``: in numpy)."""
    query = (PlainDescribed(ds.query.descriptors, ds.query.seq_bounds, windows, "query") if plain
             else Described(ds.query.descriptors, ds.query.seq_bounds, windows, models, dev, "query"))
    ref = (PlainReference(ds.reference, windows, ds.name) if plain
           else TraverseReference(ds.reference, windows, models, dev, conf.backend, ds.name))
    truth = dataset_truth(ds, query.side.items, ref.items, conf.radius)
    out = run(methods, query, ref, truth, conf, len(ds.query), lambda m: _entry(m, conf, entries), windows=windows,
              with_torch=not plain)
    out.query_names, out.reference_names = item_names(ds.query, query.side.items), item_names(ds.reference, ref.items)
    return out


def dataset_truth(ds: Dataset, q_items: np.ndarray, r_items: np.ndarray, radius: float) -> GroundTruth:
    """What is correct for the query items ``q_items`` among the reference items ``r_items`` of ``ds``: its
    explicit positives, else the radius; a query whose correct references are all frames of ``ds`` outside
    ``r_items`` (no full window fits there) is kept, as a failure (:attr:`GroundTruth.matched`)."""
    positives = ds.positives.select(q_items, r_items) if ds.positives is not None else None
    outside = len(r_items) < len(ds.reference) and ds.positives is not None  # explicit positives of frames no item
    return ground_truth(ds.query.positions[q_items], ds.reference.positions[r_items], radius, positives, ds.name,
                        ds.position_unit, frames=ds.reference.positions,
                        matched=ds.positives.counts()[q_items] > 0 if outside else None)


def item_names(t: Traverse, items: np.ndarray) -> list[str] | None:
    """The image names of the frames ``items`` of ``t`` (None when it has none)."""
    return [t.names[i] for i in items] if t.names else None
