"""Choosing HVPR's shortlist size K and fused weight λ on a validation split (never on test).

:func:`hvpr_grid` scores a grid of ``(K, λ)`` for one HVPR method in one pass: the shortlist is searched
once at the largest K, the matcher scores its candidates once, and every ``(K, λ)`` is then an argmin
over the first K columns of ``matcher / L_m + λ · d_shortlist`` (the score
:func:`seqnet.matching.hvpr.hvpr_search` orders by; λ = 0 is the paper's re-ranking). Recall@1 of each
setting is what :func:`seqnet.eval.evaluate.evaluate` reports for that method with those settings.

:func:`select_hvpr` picks, for each HVPR method on its own (its K, or ``hvpr-fused``'s K and λ: a method's
choice never depends on the other methods listed) among the settings the caller left free, the best val
Recall@1; a tie keeps the default (else the smallest K, then the λ nearest the default), and says what it
picked and why (:class:`Choice`, one per method).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.log import counted, logger
from ..core.stage import Written
from ..data.traverse import Dataset
from ..methods.grammar import FRAME_FEATURES, parse_method
from ..metrics.recall import VAL_MIN
from ..reference.traverse import TraverseReference
from ..sequence.described import Described
from .config import EvalConfig
from .evaluate import main as evaluate_main
from .evaluation import method_windows
from .notices import training_choice
from .score import dataset_truth

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

TOP_KS = (5, 10, 20, 50, 100)  # the paper's HVPR (λ = 0): its K
FUSE_TOP_KS = (50, 100, 200, 400)  # hvpr-fused: its K ...
FUSE_WEIGHTS = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0)  # ... and λ
SELECTABLE = ("top_k", "fuse_top_k", "fuse_weight")  # the EvalConfig settings :func:`select_hvpr` may choose


@dataclasses.dataclass(frozen=True)
class Choice:
    """What :func:`select_hvpr` chose for one method, and why.

    Attributes:
        method: the HVPR method scored; settings: the chosen ``{name: value}`` (only those left free).
        recall: its val Recall@1; default_recall: the val Recall@1 of the defaults (None: not in the grid).
        grid: every setting scored, ``[{"top_k": K, "fuse_weight": λ, "recall@1": r}, ...]``.
        queries: val queries with a correct reference; reason: one sentence.
        reference_items: the val reference's items the shortlist was drawn from (None: not known); every K at or
            above it re-ranks the whole val reference, so only one such K is scored.
    """

    method: str
    settings: dict[str, Any]
    recall: float
    default_recall: float | None
    grid: list[dict[str, Any]]
    queries: int
    reason: str
    reference_items: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def hvpr_grid(ds: Dataset, models: Mapping[str, SeqNet], conf: EvalConfig, method: str, top_ks: Sequence[int],
              weights: Sequence[float], sides: dict | None = None) -> tuple[np.ndarray, int]:
    """Recall@1 ``[len(top_ks), len(weights)]`` of the HVPR ``method`` on ``ds`` (one split) with shortlist size
    ``top_ks[i]`` and fused weight ``weights[j]`` (0: the matcher alone), on the query items
    :func:`~seqnet.eval.evaluate.evaluate` gives it under ``conf``; and the queries counted (the denominator).
    ``sides``: a dict kept by the caller across methods, so that each window group's query and reference sides
    are described once."""
    m = parse_method(method)
    if m.kind != "hvpr":
        raise ConfigError(f"hvpr_grid scores an HVPR method, got {method!r}")
    if not top_ks or not weights or min(top_ks) < 1 or min(weights) < 0:
        raise ConfigError(f"need shortlist sizes >= 1 and weights >= 0, got {list(top_ks)} and {list(weights)}")
    models = dict(models)
    conf = conf.resolve(models, ds.radius)
    dev = get_device(conf.device)
    for model in models.values():
        model.to(dev).eval()
    windows = _windows_of(conf, m.name)
    sides = {} if sides is None else sides
    if windows not in sides:
        query = Described(ds.query.descriptors, ds.query.seq_bounds, windows, models, dev, "query")
        ref = TraverseReference(ds.reference, windows, models, dev, conf.backend, ds.name)
        sides[windows] = query, ref, dataset_truth(ds, query.side.items, ref.items, conf.radius)
    query, ref, truth = sides[windows]
    dist, ranked = ref.search(m.shortlist, query.items(m.shortlist), max(top_ks))
    frames = FRAME_FEATURES[m.frames]
    scores = ref.rerank(frames, m.matcher, query.frames(frames), query.match_starts, ranked)
    scores = np.asarray(scores.detach().cpu().numpy() if hasattr(scores, "detach") else scores)
    hits = truth.hits(ranked)  # [M, K_max]
    keep = truth.has_positive() if conf.recall_denominator == "positives" else np.ones(len(hits), bool)
    return grid_recall(scores, np.asarray(dist), hits[keep], keep, windows.match_len, top_ks, weights), \
        int(keep.sum())


def _windows_of(conf: EvalConfig, method: str) -> Any:
    """The windows :func:`~seqnet.eval.evaluate.evaluate` gives ``method`` under ``conf`` (resolved)."""
    m = parse_method(method)
    listed = [parse_method(n) for n in conf.methods] if m.name in conf.methods else [m]
    return next(w for w, ms in method_windows(listed, conf.windows, conf.common_queries).items()
                if any(x.name == m.name for x in ms))


def reference_items(ds: Dataset, models: Mapping[str, SeqNet], conf: EvalConfig, method: str) -> int:
    """How many reference items of ``ds`` the HVPR ``method`` shortlists from under ``conf`` (frames whose windows
    fit): a K at or above it re-ranks them all."""
    windows = _windows_of(conf.resolve(dict(models), ds.radius), method)
    return len(windows.side(len(ds.reference), ds.reference.seq_bounds).items)


def grid_ks(ks: Sequence[int], items: int, default: int) -> list[int]:
    """``ks`` (sorted, once each) with the values at or above ``items`` (the reference's items: each re-ranks all of
    them, one setting) kept once: the default when it is one of them, else the smallest."""
    ks = sorted(set(ks))
    over = [k for k in ks if k >= items]
    return [k for k in ks if k < items] + ([default if default in over else over[0]] if over else [])


def grid_recall(scores: np.ndarray, dist: np.ndarray, hits: np.ndarray, keep: np.ndarray, match_len: int,
                top_ks: Sequence[int], weights: Sequence[float]) -> np.ndarray:
    """Recall@1 ``[len(top_ks), len(weights)]`` from the matcher ``scores [M, K_max]`` and shortlist distances
    ``dist [M, K_max]`` of each query's shortlist, whether each candidate is correct (``hits [M', K_max]`` of the
    queries ``keep [M]`` counted): the first candidate of the lowest ``scores / L_m + λ · dist`` among the first
    K (λ = 0: the lowest score, ties in shortlist order, as :func:`seqnet.matching.hvpr.order`)."""
    out = np.zeros((len(top_ks), len(weights)))
    if not keep.any():
        return out
    s, d = scores[keep].astype(np.float32), dist[keep].astype(np.float32)
    rows = np.arange(len(s))
    for i, k in enumerate(top_ks):
        k = min(int(k), s.shape[1])
        for j, w in enumerate(weights):
            fused = s[:, :k] if w == 0 else s[:, :k] / np.float32(match_len) + np.float32(w) * d[:, :k]
            out[i, j] = hits[rows, np.argmin(fused, axis=1)].mean()
    return out


def pick(recall: np.ndarray, top_ks: Sequence[int], weights: Sequence[float],
         default: tuple[int, float]) -> tuple[int, int]:
    """The index ``(i, j)`` of the best Recall@1; a tie keeps ``default`` ``(K, λ)`` when it is among the best,
    else the smallest K, then the λ nearest the default's."""
    best = np.isclose(recall, recall.max(), rtol=0, atol=1e-12)
    cells = [(i, j) for i, j in zip(*np.nonzero(best), strict=True)]
    for i, j in cells:
        if (top_ks[i], weights[j]) == default:
            return int(i), int(j)
    return min(cells, key=lambda c: (top_ks[c[0]], abs(weights[c[1]] - default[1]), weights[c[1]]))


def select_hvpr(ds: Dataset, models: Mapping[str, SeqNet], conf: EvalConfig, free: Sequence[str] = SELECTABLE,
                where: str = "val") -> tuple[EvalConfig, list[Choice]]:
    """``conf`` with the settings of ``free`` (of :data:`SELECTABLE`) chosen on ``ds`` (a validation split: the
    caller's promise; it is never given test) by val Recall@1, for each HVPR method of ``conf.methods`` on its
    own (``method_top_k``, ``method_fuse_weight``: a method's choice never depends on the other methods listed),
    and what was chosen (one :class:`Choice` per method scored, in the order listed: ``top_k`` for every HVPR
    method but ``hvpr-fused``, ``fuse_top_k`` / ``fuse_weight`` for each ``hvpr-fused``; a method whose models
    are not given is left as it is). ``where`` names ``ds`` in the reasons."""
    free = [f for f in free if f in SELECTABLE]
    methods = [parse_method(n) for n in dict.fromkeys(conf.resolve(dict(models), ds.radius).methods)]
    hvprs = [m for m in methods if m.kind == "hvpr" and set(m.models()) <= set(models)]
    choices, top_ks, weights, sides = [], dict(conf.method_top_k or {}), dict(conf.method_fuse_weight or {}), {}
    for m in hvprs:
        names = tuple(f for f in (("fuse_top_k", "fuse_weight") if m.fused else ("top_k",)) if f in free)
        if not names:
            continue
        default = {"top_k": conf.shortlist_size(m), "fuse_weight": conf.weight(m)}
        ch = _choose(ds, models, conf, m.name, names, default, where, sides)
        choices.append(ch)
        for name, value in ch.settings.items():
            (weights if name == "fuse_weight" else top_ks)[m.name] = value
    return conf.merge(method_top_k=top_ks or None, method_fuse_weight=weights or None), choices


def _choose(ds: Dataset, models: Mapping[str, SeqNet], conf: EvalConfig, method: str, names: tuple[str, ...],
            default: dict[str, Any], where: str, sides: dict) -> Choice:
    """One method's grid (the settings ``names`` free, the others at ``default``), scored and picked."""
    k_free = bool({"top_k", "fuse_top_k"} & set(names))
    w_free = "fuse_weight" in names
    items = reference_items(ds, models, conf, method)
    every_k = {*(TOP_KS if "top_k" in names else FUSE_TOP_KS), default["top_k"]}
    top_ks = grid_ks(every_k, items, default["top_k"]) if k_free else [default["top_k"]]
    weights = sorted({*FUSE_WEIGHTS, default["fuse_weight"]}) if w_free else [default["fuse_weight"]]
    recall, queries = hvpr_grid(ds, models, conf, method, top_ks, weights, sides)
    i, j = pick(recall, top_ks, weights, (default["top_k"], default["fuse_weight"]))
    k_name = "top_k" if "top_k" in names else "fuse_top_k"
    settings = {**({k_name: int(top_ks[i])} if k_free else {}), **({"fuse_weight": float(weights[j])} if w_free
                                                                   else {})}
    grid = [{"top_k": int(k), "fuse_weight": float(w), "recall@1": round(float(recall[a, b]), 6)}
            for a, k in enumerate(top_ks) for b, w in enumerate(weights)]
    d = recall[top_ks.index(default["top_k"]), weights.index(default["fuse_weight"])]
    n_best = int(np.isclose(recall, recall.max(), rtol=0, atol=1e-12).sum())
    shown = ", ".join(f"{'K' if n != 'fuse_weight' else 'λ'} {v:g}" for n, v in settings.items())
    if n_best > 1:
        why = (f"tied with {n_best - 1} other setting{'s' if n_best > 2 else ''}; "
               + ("the default kept" if (top_ks[i], weights[j]) == (default["top_k"], default["fuse_weight"])
                  else "the smallest K kept"))
    else:
        why = f"the default scored {d:.3f}" if recall[i, j] > d else "the default"
    reason = (f"{method}: {shown} chosen on {where} ({counted(queries, 'query', 'queries')}): R@1 "
              f"{recall[i, j]:.3f}, the best of {counted(recall.size, 'setting')} ({why})")
    if k_free and (sum(k >= items for k in every_k) > 1 or top_ks[i] >= items):  # K values merged, or K = all
        reason += (f"; the val reference has {items} items, so every K of {items} or more re-ranks all of them "
                   "(scored once)" + (f", K {top_ks[i]} too: no shortlist on val" if top_ks[i] >= items else ""))
    return Choice(method, settings, float(recall[i, j]), float(d), grid, queries, reason, items)


def holds_val_queries(ds: Dataset, split: str) -> bool:
    """Whether the queries of ``split`` (a name or a range of ``ds``) and of its ``val`` split overlap."""
    rng, val = ds.ranges(split), ds.ranges("val")
    if rng is None or val is None:
        return False
    (a, b), (c, d) = rng["query"], val["query"]
    return max(a, c) < min(b, d)


def main(conf: EvalConfig, dataset: str | Path, out: str | Path | None, models: Sequence[str | Path] = (),
         shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None,
         choose: Sequence[str] = SELECTABLE, **outputs: Any) -> Written:
    """:func:`seqnet.eval.evaluate.main` (``outputs``: its output options) with the settings of ``choose`` chosen
    first on the dataset's ``val`` split (:func:`choose_on_val`, on the dataset and models the evaluation loads)
    when an HVPR method is evaluated; what was chosen and why goes into the results (``"selection"``)."""
    hvpr = conf.methods is None or any(parse_method(n).kind == "hvpr" for n in conf.methods)
    prepare = (lambda ds, split, loaded, c: choose_on_val(ds, split, loaded, c, choose, dataset)) \
        if choose and hvpr else None
    return evaluate_main(conf, dataset, out, models, shortlist_model, rerank_model, prepare=prepare, **outputs)


def choose_on_val(ds: Dataset, split: str, models: Mapping[str, SeqNet], conf: EvalConfig,
                  choose: Sequence[str], dataset: str | Path | None = None) -> tuple[EvalConfig, dict[str, Any] | None]:
    """``conf`` with the settings of ``choose`` chosen on ``ds``'s val split (:func:`select_hvpr`) for the
    evaluation of ``split``, and the results' ``"selection"`` entry (None: nothing to say). Without a val split,
    or evaluating val itself, nothing is chosen; nor when ``split`` holds val queries (``all``), or the choice
    fails (no val query with a full window or a correct reference): the defaults kept, and said. A choice made on
    val queries that are training queries of the models (``ds`` the dataset directory ``dataset``) is said too
    (``"leakage"``: :func:`training_choice`)."""
    if split == "val":
        return conf, None
    if "val" not in (ds.splits or {}):  # nothing to choose on: the defaults kept, said (they can cap an HVPR)
        flags, kept = "/".join("--" + c.replace("_", "-") for c in choose), conf.hvpr_settings(choose)
        return conf, {"selection": {"hvpr": [], "not_chosen": f"HVPR settings not chosen: dataset {ds.name!r} has "
                                    f"no val split to choose them on, so the defaults are kept ({kept}; hint: give "
                                    f"{flags} yourself, or rebuild the dataset with --split val=A:B)"}}
    if holds_val_queries(ds, split):
        return conf, {"selection": {"hvpr": [], "not_chosen": f"HVPR settings not chosen on the val split: the "
                                    f"evaluated split {split!r} holds val queries, which would score their own "
                                    "choice (the defaults kept)"}}
    try:
        conf, choices = select_hvpr(ds.split("val"), models, conf, choose, "the val split")
    except ConfigError as e:  # said in the results; an error of the evaluation itself is its own (one line)
        logger.debug("HVPR settings not chosen on the val split: %s", e)
        return conf, {"selection": {"hvpr": [], "not_chosen": f"HVPR settings not chosen on the val split (the "
                                                               f"defaults kept): {e}"}}
    choices = [against(c, ds.split(split), models, conf) for c in choices]
    leak = {"leakage": said} if dataset is not None and (said := training_choice(models, dataset, ds, choices)) \
        else {}
    few = min((c.queries for c in choices), default=VAL_MIN)
    if few < VAL_MIN:  # chosen all the same, as training chooses its epoch: said (once evaluated), with the remedy
        said = (f"HVPR settings chosen on {few} val quer{'y' if few == 1 else 'ies'} (1 query = "
                f"{1 / max(few, 1):.2f} of R@1): the choice is mostly chance; about {VAL_MIN} or more are needed, "
                f"or give {' / '.join('--' + c.replace('_', '-') for c in choose)} yourself")
        return conf, {"selection": {"hvpr": [c.to_dict() for c in choices], "warning": said, **leak}}
    return conf, ({"selection": {"hvpr": [c.to_dict() for c in choices], **leak}} if choices else None)


def against(choice: Choice, evaluated: Dataset, models: Mapping[str, SeqNet], conf: EvalConfig) -> Choice:
    """``choice`` with the evaluated reference's items beside the val reference's when the K grid reached past
    the latter (its reason says so): a K chosen where it re-ranked every val item is a shortlist of the larger
    evaluated reference, a setting val did not score; the hint names what to do."""
    flag = "--top-k" if "top_k" in choice.settings else "--fuse-top-k"
    n, k = choice.reference_items, choice.settings.get("top_k", choice.settings.get("fuse_top_k"))
    if n is None or k is None or "; the val reference has" not in choice.reason:
        return choice
    m = reference_items(evaluated, models, conf, choice.method)
    said = f"; the evaluated reference has {m} items"
    if n <= k < m:
        said += (f", where K {k} is a shortlist that val did not score (hint: give {flag} yourself, or build the "
                 "dataset with a val split whose reference has more items than the K grid's largest)")
    return dataclasses.replace(choice, reason=choice.reason + said)
