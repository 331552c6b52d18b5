"""Evaluation: run methods on a dataset and report Recall@K with per-stage timing.

Queries are the frames whose full window (length ``seq_len``) fits inside their sequence; the
same query and reference sets are used for every method so numbers are comparable. The number of
queries left out (no full window, or no reference within the radius) is reported.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from .config import EVAL_DEFAULTS, merge
from .errors import ConfigError
from .matching import knn
from .methods import Method, parse_method
from .recall import check_radius, recall_at_k
from .sequence_descriptors import SeqNet, delta, describe_windows, smoothing
from .sequence_matching import rerank_seqmatch, seqmatch_topk
from .traverse import Dataset
from .utils import as_tensor, get_device, l2_normalize, logger
from .windows import check_seq_len, window_indices, window_offset, window_starts


@dataclasses.dataclass
class Evaluation:
    """Results of :func:`evaluate`: JSON-ready ``results`` plus rankings for plots."""

    results: dict[str, Any]
    retrieved: dict[str, np.ndarray]  # method -> [M, K] indices into r_items, best first
    q_pos: np.ndarray  # [M, P] positions of the evaluated query frames
    r_pos: np.ndarray  # [R, P] positions of the indexed reference frames
    radius: float
    q_items: np.ndarray  # [M] query frame of each evaluated query
    r_items: np.ndarray  # [R] reference frame of each indexed reference


class _Features:
    """Descriptors of one evaluation, computed once and timed (ms)."""

    def __init__(self, ds: Dataset, cfg: Mapping[str, Any], models: Mapping[str, SeqNet], device: torch.device):
        self.ds, self.models, self.device = ds, models, device
        self.L, self.mode = cfg["seq_len"], cfg["window"]
        self.q_starts, q_valid = window_starts(len(ds.query), self.L, self.mode, ds.query.seq_bounds)
        self.r_starts, r_valid = window_starts(len(ds.reference), self.L, self.mode, ds.reference.seq_bounds)
        self.q_items, self.r_items = np.flatnonzero(q_valid), np.flatnonzero(r_valid)
        self.cache: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self.ms: dict[str, float] = {}

    def get(self, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(query, reference)`` descriptors named ``name``: frames (``raw``, ``s1``,
        ``delta_frames``) or items (``single``, ``smoothing``, ``delta``, ``seqnet``, ``s1_items``)."""
        if name not in self.cache:
            t0 = time.perf_counter()
            self.cache[name] = self._compute(name)
            self.ms[name] = (time.perf_counter() - t0) * 1e3 + sum(self.ms.get(d, 0.0) for d in self._deps(name))
        return self.cache[name]

    @staticmethod
    def _deps(name: str) -> tuple[str, ...]:
        return {"single": ("raw",), "s1_items": ("s1",)}.get(name, ())

    def _compute(self, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        q, r = self.ds.query, self.ds.reference
        if name == "raw":
            return l2_normalize(as_tensor(q.descriptors)), l2_normalize(as_tensor(r.descriptors))
        if name in ("single", "s1_items"):
            fq, fr = self.get("raw" if name == "single" else "s1")
            return fq[self.q_items], fr[self.r_items]
        if name == "s1":
            model = self.models["s1"]
            return tuple(describe_windows(t.descriptors, np.arange(len(t))[:, None], model, device=self.device,
                                          progress="S_1") for t in (q, r))  # type: ignore[return-value]
        if name == "delta_frames":
            return tuple(describe_windows(t.descriptors, window_indices(len(t), self.L, self.mode, t.seq_bounds), delta,
                                          device=self.device) for t in (q, r))  # type: ignore[return-value]
        fn = {"smoothing": smoothing, "delta": delta}.get(name) or self.models["seqnet"]
        out = []
        for t, starts, items in ((q, self.q_starts, self.q_items), (r, self.r_starts, self.r_items)):
            idx = starts[items][:, None] + np.arange(self.L)[None, :]
            out.append(describe_windows(t.descriptors, idx, fn, device=self.device, progress=name))
        return out[0], out[1]


_ITEM_FEATURE = {"single": "single", "s1": "s1_items", "smoothing": "smoothing", "delta": "delta", "seqnet": "seqnet"}
_FRAME_FEATURE = {"raw": "raw", "s1": "s1", "delta": "delta_frames"}


def _run_method(m: Method, f: _Features, cfg: Mapping[str, Any]) -> tuple[np.ndarray, dict[str, float]]:
    """Rank reference items for every query item; returns ``([M, K] items, timing_ms)``."""
    k_max, dev = max(cfg["ks"]), f.device
    timing: dict[str, float] = {}
    if m.kind in ("knn", "hvpr"):
        fq, fr = f.get(_ITEM_FEATURE[m.shortlist])
        t0 = time.perf_counter()
        k = max(k_max, cfg["top_k"]) if m.kind == "hvpr" else k_max
        _, ranked = knn(fq, fr, k, backend=cfg["backend"], device=str(dev))
        timing["shortlist" if m.kind == "hvpr" else "retrieval"] = (time.perf_counter() - t0) * 1e3
        timing["descriptors"] = f.ms[_ITEM_FEATURE[m.shortlist]]
    if m.kind in ("seqmatch", "hvpr"):
        sq, sr = f.get(_FRAME_FEATURE[m.rerank])
        timing["descriptors"] = timing.get("descriptors", 0.0) + f.ms[_FRAME_FEATURE[m.rerank]]
        t0 = time.perf_counter()
        qs, rs = f.q_starts[f.q_items], f.r_starts[f.r_items]
        if m.kind == "seqmatch":
            _, ranked = seqmatch_topk(sq, sr, f.L, k_max, qs, rs, device=str(dev), progress="SeqMatch")
            timing["seqmatch"] = (time.perf_counter() - t0) * 1e3
        else:
            top = min(cfg["top_k"], ranked.shape[1])
            head, _ = rerank_seqmatch(sq, sr, f.L, qs, rs, ranked[:, :top], device=str(dev))
            ranked = np.concatenate([head, ranked[:, top:]], axis=1)
            timing["rerank"] = (time.perf_counter() - t0) * 1e3
    timing["total"] = sum(timing.values())
    return ranked, timing


def resolve_eval_config(overrides: Mapping[str, Any] | None, ds: Dataset) -> dict[str, Any]:
    """Merge ``overrides`` onto :data:`EVAL_DEFAULTS` and validate against the dataset."""
    cfg = merge(EVAL_DEFAULTS, overrides)
    check_seq_len(cfg["seq_len"])
    cfg["radius"] = check_radius(ds.radius if cfg["radius"] is None else cfg["radius"])
    cfg["extra_radii"] = [check_radius(r) for r in cfg["extra_radii"]]
    if not cfg["methods"]:
        raise ConfigError("no methods given; valid: see `seqnet eval --help`")
    if isinstance(cfg["top_k"], bool) or not isinstance(cfg["top_k"], (int, np.integer)) or cfg["top_k"] < 1:
        raise ConfigError(f"top_k must be an integer >= 1, got {cfg['top_k']!r}")
    ks = cfg["ks"]
    if not ks or any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1 for k in ks):
        raise ConfigError(f"ks must be a non-empty list of integers >= 1, got {ks!r}")
    cfg["ks"] = [int(k) for k in ks]
    window_offset(cfg["seq_len"], cfg["window"])  # validates the window mode
    if cfg["backend"] not in ("torch", "faiss"):
        raise ConfigError(f"k-NN backend {cfg['backend']!r} is not one of ('torch', 'faiss')")
    get_device(cfg["device"])  # validates the device
    return cfg


def evaluate(
    ds: Dataset, config: Mapping[str, Any] | None = None, models: Mapping[str, SeqNet] | None = None
) -> Evaluation:
    """Evaluate methods on ``ds`` (already restricted to the split to evaluate).

    Args:
        ds: dataset (reference + query traverses, radius).
        config: overrides of :data:`seqnet.config.EVAL_DEFAULTS`.
        models: trained models by role: ``{"seqnet": S_L, "s1": S_1}`` (optional).

    Returns:
        :class:`Evaluation` whose ``results`` follow the ``--json`` schema.
    """
    models = dict(models or {})
    cfg = resolve_eval_config(config, ds)
    methods = [parse_method(n, set(models), cfg["shortlist"], cfg["rerank"]) for n in cfg["methods"]]
    uses_delta = [m.name for m in methods if "delta" in (m.shortlist, m.rerank)]
    if uses_delta and cfg["seq_len"] < 2:
        raise ConfigError(f"method(s) {', '.join(uses_delta)} use Delta descriptors, which need seq_len >= 2 "
                          f"(got {cfg['seq_len']}); use a longer --seq-len or other methods")
    for role, model in models.items():
        if model.in_dims != ds.query.dim:
            raise ConfigError(f"the {role} model expects D={model.in_dims} descriptors "
                              f"but the dataset has D={ds.query.dim}")
    for side, t in (("query", ds.query), ("reference", ds.reference)):
        if cfg["seq_len"] > len(t):
            raise ConfigError(f"seq_len={cfg['seq_len']} is longer than the {side} traverse of dataset "
                              f"{ds.name!r} ({len(t)} frames); use a shorter --seq-len")
    dev = get_device(cfg["device"])
    for model in models.values():
        model.to(dev).eval()
    f = _Features(ds, cfg, models, dev)
    if len(f.q_items) == 0 or len(f.r_items) == 0:
        raise ConfigError(f"no {'query' if len(f.q_items) == 0 else 'reference'} frame has a full window of "
                          f"seq_len={cfg['seq_len']} inside its sequence; use a shorter --seq-len")
    q_pos, r_pos = ds.query.positions[f.q_items], ds.reference.positions[f.r_items]
    results: dict[str, Any] = {}
    retrieved: dict[str, np.ndarray] = {}
    for m in methods:
        ranked, timing = _run_method(m, f, cfg)
        retrieved[m.name] = ranked
        rec = recall_at_k(ranked, q_pos, r_pos, cfg["radius"], cfg["ks"])
        entry: dict[str, Any] = {k: v for k, v in rec.items() if k.startswith("recall@")}
        entry.update(queries=rec["queries"], no_positive=rec["no_positive"],
                     no_full_window=int(len(ds.query) - len(f.q_items)),
                     timing_ms={k: round(v, 3) for k, v in timing.items()})
        if cfg["extra_radii"]:
            entry["radii"] = {str(r): {k: v for k, v in recall_at_k(ranked, q_pos, r_pos, r, cfg["ks"]).items()}
                              for r in cfg["extra_radii"]}
        results[m.name] = entry
        logger.info("%s: R@1 %.3f (%d queries)", m.name, entry.get("recall@1", float("nan")), entry["queries"])
    out = {"methods": results, "config": {**cfg, "dataset": ds.name, "device": str(dev),
                                          "models": {k: v.config() for k, v in models.items()}}}
    return Evaluation(out, retrieved, q_pos, r_pos, cfg["radius"], f.q_items, f.r_items)
