"""Evaluation: run methods on a dataset and report Recall@K with per-stage timing.

A sequence method's queries are the frames whose windows (L frames for sequence descriptors, L_m for
the sequence matchers) fit inside their sequence, and its references the reference frames whose
windows fit; a single-frame method (``single``, ``s1``) needs no window: it queries and indexes every
frame (``common_queries``: every method on the sequence methods' items, one query set). Each
method's entry reports its queries and the number left out (no full window, and why; no reference
within the radius). See :mod:`seqnet.eval.evaluation`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.config import Config, check_bool, check_choice, check_float, check_int, check_ints
from ..core.devices import check_device, get_device
from ..core.errors import ConfigError
from ..core.log import logger
from ..core.stage import Written
from ..data.resample import RESAMPLE_SIDES, resample_dataset
from ..data.traverse import Dataset, Traverse, default_split
from ..methods.checks import check_inputs, leakage, model_lengths
from ..methods.grammar import FUSE_WEIGHT, Method, default_methods, parse_method
from ..methods.protocol import Reference
from ..methods.rank import rank
from ..metrics.calibration import RISK, check_target
from ..metrics.recall import RECALL_DENOMINATORS, GroundTruth, check_radius, ground_truth
from ..reference.plain import PlainReference, runs_plain
from ..reference.traverse import TraverseReference
from ..search.knn import KNN_BACKENDS
from ..security.text import shown
from ..sequence.described import Described
from ..sequence.npdescribed import PlainDescribed
from ..sequence.windows import WINDOW_MODES, Windows, WindowSettings
from .calibrated import add_calibration, check_calibration_split
from .evaluation import Evaluation, merge, method_windows, no_window_reason
from .outputs import EvalOutputs
from .results import method_results

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


@dataclasses.dataclass(frozen=True)
class EvalConfig(WindowSettings, Config):
    """Settings of :func:`evaluate` (see ``seqnet eval --help``).

    Attributes:
        methods: method names (:mod:`seqnet.methods.grammar`); None: every default method the models allow.
        seq_len: window length L of the sequence descriptors (None: the S_L model's, else 5).
        match_len: length L_m of the sequence matchers (None: L).
        window: ``"centred"`` (the paper's) or ``"causal"`` (online).
        radius: localisation radius (None: the dataset's); a retrieved reference is correct within it (≤).
        extra_radii: further radii to report.
        ks: the K of Recall@K; recall_denominator: ``positives`` (queries with a correct reference, the
            original code's) or ``all`` (every evaluated query): :data:`seqnet.metrics.recall.RECALL_DENOMINATORS`.
        top_k: HVPR shortlist size K.
        fuse_weight, fuse_top_k: λ of the fused score and shortlist size K of ``hvpr-fused``
            (defaults :data:`seqnet.methods.grammar.FUSE_WEIGHT`, :data:`seqnet.methods.grammar.FUSED_TOP_K`).
        split: the split evaluated by :func:`main` (None: test when defined, else all).
        resample_every, resample_side: keep every N-th frame (recorded order) of the query, reference or both
            sides of the evaluated split (:func:`seqnet.data.resample.resample_dataset`; None: all frames).
        backend: k-NN backend (a key of :data:`seqnet.search.knn.KNN_BACKENDS`).
        device: torch device (auto: CUDA when present).
        allow_mismatch: go on (with a warning) when reference and query descriptors, or a model and
            the descriptors, were made differently; by default each is an error. (An S_L model at another
            L >= w than it was trained with needs no flag: one info line, ``model_seq_len`` in the results.)
        common_queries: evaluate every method on the sequence methods' query and reference items (the
            paper's tables: one query set); by default a single-frame method (``single``, ``s1``) queries and
            indexes every frame (:mod:`seqnet.eval.evaluation`).
        target_precision, calibrate_split, risk: with a target, :func:`main` also evaluates ``calibrate_split``
            and gives each method a confidence threshold calibrated there, whose precision is ≥ the target
            with probability ≥ 1 − ``risk`` (:mod:`seqnet.metrics.calibration`), applied to the evaluated split.
    """

    methods: tuple[str, ...] | None = None
    seq_len: int | None = None
    match_len: int | None = None
    window: str = "centred"
    radius: float | None = None
    extra_radii: tuple[float, ...] = ()
    ks: tuple[int, ...] = (1, 5, 10, 20, 100)
    recall_denominator: str = "positives"
    top_k: int = 20
    fuse_weight: float = FUSE_WEIGHT
    fuse_top_k: int | None = None
    split: str | None = None
    resample_every: int | None = None
    resample_side: str = "query"
    backend: str = "torch"
    device: str = "auto"
    allow_mismatch: bool = False
    common_queries: bool = False
    target_precision: float | None = None
    calibrate_split: str = "val"
    risk: float = RISK

    def __post_init__(self) -> None:
        self._set("allow_mismatch", check_bool("allow_mismatch", self.allow_mismatch))
        self._set("common_queries", check_bool("common_queries", self.common_queries))
        if self.methods is not None:
            if isinstance(self.methods, str) or not self.methods:
                raise ConfigError(f"methods must be a non-empty list of method names, got {self.methods!r}")
            self._set("methods", tuple(parse_method(m).name for m in self.methods))
        for key in ("seq_len", "match_len", "resample_every"):
            if getattr(self, key) is not None:
                self._set(key, check_int(key, getattr(self, key), 1))
        check_choice("resample side", self.resample_side, RESAMPLE_SIDES)
        check_choice("recall denominator", self.recall_denominator, RECALL_DENOMINATORS)
        check_choice("window mode", self.window, WINDOW_MODES)
        if self.radius is not None:
            self._set("radius", check_radius(self.radius))
        self._set("extra_radii", tuple(check_radius(r) for r in self.extra_radii))
        self._set("ks", check_ints("ks", self.ks, 1))
        self._set("top_k", check_int("top_k", self.top_k, 1))
        self._set("fuse_weight", check_float("fuse_weight", self.fuse_weight, 0.0))
        if self.fuse_top_k is not None:
            self._set("fuse_top_k", check_int("fuse_top_k", self.fuse_top_k, 1))
        check_choice("k-NN backend", self.backend, KNN_BACKENDS)
        check_device(self.device)  # validates the device name
        if self.target_precision is not None:
            self._set("target_precision", check_target(self.target_precision, self.risk)[0])
        self._set("risk", check_target(0.5, self.risk)[1])

    def resolve(self, models: Mapping[str, SeqNet], radius: float) -> EvalConfig:
        """L (the S_L model's when unset), the radius (the dataset's when unset) and the methods (the defaults
        the models allow when unset), resolved once."""
        model_len = getattr(models.get("seqnet"), "seq_len", None)
        seq_len = Windows.resolve(self.seq_len, None, self.window, model_len).seq_len
        return self.replace(radius=radius if self.radius is None else self.radius, seq_len=seq_len,
                            methods=self.methods or default_methods(models, seq_len))

    def shortlist_size(self, m: Method) -> int:
        """The HVPR shortlist size K of method ``m`` (``fuse_top_k`` for ``hvpr-fused``)."""
        return m.shortlist_size(self.top_k, self.fuse_top_k)


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
        info["fuse_weight"] = conf.fuse_weight
    info["models"] = {r: models[r].config() for r in sorted(m.models())}
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
    parts = [_evaluate_group(ds, ms, w, conf, models, dev, plain) for w, ms in groups.items()]
    out = merge(parts, conf.methods)
    out.results["config"] = {**conf.to_dict(), "dataset": ds.name, "device": str(dev),
                             "ground_truth": "explicit positives" if ds.positives is not None else "radius",
                             "models": {k: v.config() for k, v in models.items()},
                             "model_seq_len": model_lengths(models)}
    out.dataset, out.frame_names = ds, (ds.query.names, ds.reference.names)
    return out


def _evaluate_group(ds: Dataset, methods: list[Method], windows: Windows, conf: EvalConfig,
                    models: Mapping[str, SeqNet], dev: Any, plain: bool = False) -> Evaluation:
    """The methods that share ``windows``, on those windows' query and reference items (``plain``: in numpy)."""
    query = (PlainDescribed(ds.query.descriptors, ds.query.seq_bounds, windows, "query") if plain
             else Described(ds.query.descriptors, ds.query.seq_bounds, windows, models, dev, "query"))
    ref = (PlainReference(ds.reference, windows, ds.name) if plain
           else TraverseReference(ds.reference, windows, models, dev, conf.backend, ds.name))
    truth = dataset_truth(ds, query.side.items, ref.items, conf.radius)
    out = run(methods, query, ref, truth, conf, len(ds.query), lambda m: _entry(m, conf, models), windows=windows)
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


def run(methods: Sequence[Method], query: Described, ref: Reference, truth: GroundTruth, conf: EvalConfig,
        n_frames: int, info: Callable[[Method], dict[str, Any]],
        extra: Callable[[Method, np.ndarray], dict[str, Any]] | None = None,
        windows: Windows | None = None) -> Evaluation:
    """The one evaluation loop: rank every method against ``ref`` (:func:`seqnet.methods.rank.rank`), score
    it (Recall@K, PR, AUC) and time it; ``info(m)`` describes the method, ``extra(m, items)`` adds entries
    (a map's shortlist recall). ``n_frames``: query frames, for the count left out (no full window) under
    ``windows`` (default ``conf.windows``), and why."""
    windows = windows or conf.windows
    left_out = int(n_frames - len(truth.q_pos))
    why = {"no_full_window_reason": no_window_reason(windows)} if left_out else {}
    results: dict[str, Any] = {}
    retrieved, scores, confidence = {}, {}, {}
    for m in methods:
        ref.check_method(m)
        scores[m.name], retrieved[m.name], timing = rank(m, query, ref, max(conf.ks), conf.shortlist_size(m),
                                                         m.fuse_weight(conf.fuse_weight))
        timing["total"] = sum(timing.values())
        entry, confidence[m.name] = method_results(scores[m.name], retrieved[m.name], truth, conf.ks,
                                                   conf.extra_radii, conf.recall_denominator)
        entry.update(extra(m, retrieved[m.name]) if extra else {}, no_full_window=left_out, **why,
                     timing_ms={k: round(v, 3) for k, v in timing.items()}, method=info(m))
        results[m.name] = entry
        logger.debug("%s: R@1 %.3f (%d queries)", m.name, entry.get("recall@1", float("nan")), entry["queries"])
    return Evaluation({"methods": results}, retrieved, scores, truth, query.items_index, ref.items, confidence,
                      windows=windows)


def main(conf: EvalConfig, dataset: str | Path, out: str | Path | None, models: Sequence[str | Path] = (),
         shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None,
         per_query: str | Path | None = None, report: Any = None, figures: bool = False, overwrite: bool = False,
         json: str | Path | None = None, extra: Mapping[str, Any] | None = None) -> Written:
    """hloc-style stage: evaluate ``conf.split`` of the dataset directory ``dataset`` with the model
    checkpoints given (``extra``: entries added to the results); writes ``out/results.json`` (results,
    resolved config, inputs), with ``figures``
    ``out/pr_curve.png``, with ``report`` (a :class:`seqnet.report.html.ReportConfig`) ``out/report.html``,
    with ``per_query`` one row per method and query (``.csv`` or ``.jsonl``, ...), with ``json`` a copy of
    the results: :class:`seqnet.eval.outputs.EvalOutputs` (``out`` None: no folder); returns the results
    path and the results."""
    outputs = EvalOutputs(out, per_query, json, figures, report, overwrite)
    with outputs.session(conf.methods):  # a second evaluation into the same folder is refused (exit 1)
        ev = _evaluate_dir(conf, dataset, models, shortlist_model, rerank_model)
        ev.results.update(extra or {})
        return outputs.write(ev)


def _evaluate_dir(conf: EvalConfig, dataset: str | Path, models: Sequence[str | Path],
                  shortlist_model: str | Path | None, rerank_model: str | Path | None) -> Evaluation:
    from ..data.io import load_dataset
    from ..sequence.checkpoints import load_models

    ds = load_dataset(dataset)
    split = default_split(conf.split, ds.splits)
    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    if conf.target_precision is not None:
        check_calibration_split(ds, conf.calibrate_split, split)
    ev = evaluate(ds.split(split), conf.replace(split=split), loaded)
    if conf.target_precision is not None:
        cal = evaluate(ds.split(conf.calibrate_split), conf.replace(split=conf.calibrate_split), loaded)
        add_calibration(ev, cal, conf.target_precision, conf.risk, conf.calibrate_split)
    ev.results["config"]["dataset_path"] = str(dataset)
    leaks = leakage(loaded, dataset, ds, split)
    if leaks:
        ev.results["leakage"] = leaks
        for line in leaks:
            logger.warning("%s", shown(line))  # it names checkpoints' records: text from files
    ev.results["inputs"] = {"dataset": str(Path(dataset).resolve()),
                            "models": [str(Path(p).resolve()) for p in (*models, shortlist_model, rerank_model) if p]}
    return ev
