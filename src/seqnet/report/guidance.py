"""Learned methods below their model-free counterparts, said with the likely cause.

A learned method (one that needs a trained model: ``s1``, ``seqnet``, ``s1+<matcher>``, HVPR on S_L or
S_1) should beat the method that does the same without the model, on the same data:

* ``s1`` against ``single`` (the frame descriptor it maps);
* ``seqnet`` against ``smoothing`` / ``delta`` / ``delta-paper`` (model-free sequence descriptors);
* ``<learned frames>+<matcher>`` against ``raw+<matcher>``;
* a learned HVPR (``hvpr``, ``hvpr-seqnet:...``, ``hvpr-fused``, ``hvpr-<d>:s1+<matcher>``) against
  ``raw+<matcher>`` and any model-free HVPR with that matcher.

:func:`learned_below_baseline` is a pure function of an evaluation's results (``results.json``: its
``methods`` and ``config``) giving one :class:`Note` per learned method whose R@1 (else the smallest K
evaluated) is below the best of its counterparts present in the results by at least one query;
:func:`likely_causes` reads what the results record (the models' D, their training L against the evaluation's
L, the queries, an HVPR's shortlist recall) and names the usual causes. ``seqnet eval`` prints the notes under
its table (:func:`format_notes`), the HTML report has them in a section of their own.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from ..core.errors import ConfigError
from ..core.log import counted
from ..methods.checks import role_label
from ..methods.grammar import parse_method

SEQUENCE_BASELINES = ("smoothing", "delta", "delta-paper")
CHANCE_QUERIES = 5  # the largest gap in queries a sign test at 0.05 cannot tell from chance (2 * 0.5**6 < 0.05)


@dataclasses.dataclass(frozen=True)
class Note:
    """A learned method below a model-free counterpart: names, R@1 of both, the likely causes."""

    learned: str
    baseline: str
    learned_r1: float
    baseline_r1: float
    causes: tuple[str, ...]
    k: int = 1  # the K of the recalls compared: 1, else the smallest K evaluated (--ks without 1)

    def finding(self) -> str:
        """The finding alone: which method is below which."""
        return (f"{self.learned} (R@{self.k} {self.learned_r1:.3f}) is below the model-free {self.baseline} "
                f"({self.baseline_r1:.3f})")

    def text(self) -> str:
        """One line: the finding and the causes."""
        return f"{self.finding()} on the same data; likely: {'; '.join(self.causes)}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``results.json``'s ``learned_below_baseline``)."""
        return {**dataclasses.asdict(self), "causes": list(self.causes), "text": self.text()}


def counterparts(name: str, present: Mapping[str, Any]) -> list[str]:
    """The model-free methods of ``present`` that ``name`` (a learned method) should beat; [] when ``name``
    needs no model or is not a method name."""
    try:
        m = parse_method(name)
    except ConfigError:
        return []
    if not m.models():
        return []
    if m.kind == "knn":
        wanted = ["single"] if m.shortlist == "s1" else list(SEQUENCE_BASELINES)
    else:
        wanted = [f"raw+{m.matcher}"]
        if m.kind == "hvpr":
            wanted += [other for other in present if _model_free_hvpr(other, m.matcher)]
    return [w for w in dict.fromkeys(wanted) if w in present and w != name]


def _model_free_hvpr(name: str, matcher: str | None) -> bool:
    try:
        m = parse_method(name)
    except ConfigError:
        return False
    return m.kind == "hvpr" and not m.models() and m.matcher == matcher


def likely_causes(name: str, results: Mapping[str, Any], gap: tuple[float, float] | None = None) -> tuple[str, ...]:
    """The usual causes of a learned method ``name`` losing to a model-free one, most specific first: a gap
    within chance (``gap``: the two R@1), a model-free shortlist, a model on descriptors of D > 4096 (no PCA),
    a model trained at another L than evaluated, few evaluated queries; then, when nothing specific is seen,
    the causes the results cannot show (training data, val split)."""
    cfg = results.get("config", {})
    methods = results.get("methods", {})
    entry = methods.get(name, {})
    models = (entry.get("method") or {}).get("models") or cfg.get("models") or {}
    out = []
    queries = entry.get("queries")
    apart = round((gap[1] - gap[0]) * queries) if gap is not None and isinstance(queries, int) else None
    chance = apart is not None and within_chance(apart)
    if chance:
        out.append(f"possibly chance: {apart} of {queries} queries apart (a sign test cannot tell fewer than "
                   f"{CHANCE_QUERIES + 1} apart from chance)")
    m = parse_method(name)
    capped = shortlist_capped(name, entry, gap[1] if gap is not None else None)
    if capped:
        out.append(capped)
    capped = bool(capped) and "which caps its R@1" in capped  # the whole loss: no training cause beside it
    free_shortlist = m.kind == "hvpr" and bool(m.shortlist) and not parse_method(m.shortlist).models()
    if free_shortlist:
        top = (entry.get("method") or {}).get("top_k") or cfg.get("top_k")
        r1 = entry.get("recall@1", 0.0)
        better = [b for b in ("hvpr", "hvpr-fused") if isinstance((methods.get(b) or {}).get("recall@1"), float)
                  and methods[b]["recall@1"] > r1]
        absent = [b for b in ("hvpr", "hvpr-fused") if b not in methods]
        hint = f" (better here: {', '.join(better)})" if better else \
            f" (a learned shortlist: {', '.join(absent)})" if absent else ""
        out.append(f"its shortlist is the model-free {m.shortlist}: it re-ranks only the places {m.shortlist} "
                   f"ranks in its top {top or 'K'}{hint}")
    dims = sorted({int(v["in_dims"]) for v in models.values() if isinstance(v, Mapping) and "in_dims" in v})
    from ..describe.pca import PAPER_PCA_DIM  # here: the describe package (its describers, h5py) loads with it

    folded = (cfg.get("benchmark") or {}).get("pca_dims") if isinstance(cfg.get("benchmark"), Mapping) else None
    if dims and dims[-1] > PAPER_PCA_DIM and not folded:  # a PCA folded into the models reads D raw dims too
        out.append(f"D = {dims[-1]} without PCA (the paper reduces to {PAPER_PCA_DIM}; seqnet train --pca D, or seqnet "
                   "dataset from-images --pca D, fitted on the train split)")
    trained = models.get("seqnet", {}).get("seq_len") if isinstance(models.get("seqnet"), Mapping) else None
    evaluated = (entry.get("method") or {}).get("seq_len") or cfg.get("seq_len")
    if "seqnet" in m.models() and trained and evaluated and int(trained) != int(evaluated):
        out.append(f"S_L trained on windows of L={trained} but evaluated at L={evaluated} (--seq-len {trained})")
    if isinstance(queries, int) and 0 < queries < 50:
        out.append(f"only {queries} evaluated queries (one query is {1 / queries:.2f} of R@1)")
    if not (chance or capped or free_shortlist):  # the other causes (D, L, few queries) may add to it: said beside
        out.append(f"too little or too different training data for the model's D x out x w weights{_learnt(models)}, "
                   "or a val split too small to choose the epoch (the training log of seqnet train says both)")
    return tuple(out)


def _learnt(models: Mapping[str, Any]) -> str:
    """`` (S_1 learnt from 12 training queries)``: the training queries each model's checkpoint records
    (``training_queries`` of :func:`model_entries`); "" when none does."""
    said = [f"{role_label(role)} learnt from {counted(n, 'training query', 'training queries')}"
            for role, v in sorted(models.items(), key=lambda kv: kv[0] != "seqnet") if isinstance(v, Mapping)
            and type(n := v.get("training_queries")) is int and n > 0]
    return f" ({', '.join(said)})" if said else ""


def model_entries(models: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """What ``results.json`` records of each model by role (:func:`likely_causes` reads it): its architecture
    (``in_dims``, ``out_dims``, ``seq_len``, ``w``) and, when its checkpoint records its train range, the number of
    its training queries (``training_queries``)."""
    out = {}
    for role, model in models.items():
        t = getattr(model, "trained_on", None)
        rng = t.get("train_queries") if isinstance(t, Mapping) else None
        ok = isinstance(rng, list | tuple) and len(rng) == 2 and all(type(v) is int for v in rng) and rng[1] > rng[0]
        out[role] = {**model.config(), **({"training_queries": rng[1] - rng[0]} if ok else {})}
    return out


def shortlist_capped(name: str, entry: Mapping[str, Any], baseline: float | None = None) -> str | None:
    """Why an HVPR's R@1 cannot rise: its shortlist of K holds a correct reference for at most one query more than
    its R@1 counts (the entry's ``shortlist_recall``), so the re-ranking is not what loses; or that recall is below
    the model-free ``baseline`` R@1 by a query or more, so no re-ranking of that shortlist reaches it (the
    re-ranking may lose too: said beside the other causes). None when the shortlist leaves room, or is not
    recorded."""
    cap, r1, queries = entry.get("shortlist_recall"), entry.get("recall@1"), entry.get("queries")
    if not isinstance(cap, Mapping) or not isinstance(r1, (int, float)) or not isinstance(cap.get("recall"), float):
        return None
    held = f"its shortlist ({parse_method(name).shortlist} top-{cap['k']}) holds a correct reference for only " \
        f"{cap['recall']:.3f} of the queries"
    hint = "a larger --top-k (or a better shortlist)"
    if queries_apart(float(r1), cap["recall"], queries) <= 1:
        return f"{held}, which caps its R@1: the re-ranking is not what loses; {hint}"
    if baseline is not None and queries_apart(cap["recall"], baseline, queries) >= 1:
        return f"{held}, below the model-free {baseline:.3f}: no re-ranking of it reaches that; {hint}"
    return None


def queries_apart(low: float, high: float, queries: Any) -> float:
    """How many queries ``high`` is above ``low``: two recalls over the same ``queries`` are a whole number of
    queries apart (rounded: the recorded recalls may be rounded); in thousandths when the count is unknown."""
    apart = (high - low) / one_query(queries)
    return float(round(apart)) if isinstance(queries, int) and queries > 0 else apart


def within_chance(apart: int) -> bool:
    """Whether two methods ``apart`` queries apart in R@1 (on the same queries) may differ by chance: even when
    those are the only queries on which they differ, all one way (the most telling case), a two-sided sign test
    gives ``2 * 0.5**apart``, above 0.05 up to :data:`CHANCE_QUERIES`; true whatever the per-query answers."""
    return 0 <= apart <= CHANCE_QUERIES


def learned_below_baseline(results: Mapping[str, Any]) -> list[Note]:
    """One :class:`Note` per learned method of ``results`` whose R@1 is below the best of its model-free
    counterparts by at least one query (``1 / queries``; 0.001 when the count is unknown)."""
    methods = results.get("methods", {})
    k = compared_k(methods)
    key = f"recall@{k}"
    notes = []
    for name, entry in methods.items():
        r1 = entry.get(key)
        if not isinstance(r1, (int, float)):
            continue
        scored = [(float(methods[b][key]), b) for b in counterparts(name, methods)
                  if isinstance(methods[b].get(key), (int, float))]
        if not scored:
            continue
        best, base = max(scored)
        if best - float(r1) >= one_query(entry.get("queries")) - 1e-9:
            notes.append(Note(name, base, float(r1), best, likely_causes(name, results, (float(r1), best)), k))
    return notes


def one_query(queries: Any) -> float:
    """What one query is of a recall over ``queries`` (``1 / queries``; 0.001 when the count is unknown)."""
    return 1.0 / queries if isinstance(queries, int) and queries > 0 else 0.001


def compared_k(methods: Mapping[str, Any]) -> int:
    """The K whose Recall@K the notes compare: 1 when evaluated, else the smallest K of the results (``--ks``
    without 1: the notes would otherwise vanish however far below a model is)."""
    ks = {int(key.split("@")[1]) for entry in methods.values() if isinstance(entry, Mapping) for key in entry
          if key.startswith("recall@") and key.split("@")[1].isdecimal()}
    return 1 if 1 in ks or not ks else min(ks)


def format_notes(notes: list[Note]) -> list[str]:
    """The notes as printed under the results table: the learned methods with the same likely causes on one
    line."""
    groups: dict[tuple[str, ...], list[Note]] = {}
    for n in notes:
        groups.setdefault(n.causes, []).append(n)
    return [f"note: {'; '.join(n.finding() for n in group)} on the same data; likely: {'; '.join(causes)}"
            for causes, group in groups.items()]


def unmatched(results: Mapping[str, Any]) -> list[str]:
    """The learned methods of ``results`` with no model-free counterpart evaluated beside them (nothing to say
    whether the model helps), with the counterpart to add."""
    methods = results.get("methods", {})
    groups: dict[str, list[str]] = {}  # the counterpart to add -> the learned methods wanting it
    wants, below = {}, {}
    for name in methods:
        try:
            m = parse_method(name)
        except ConfigError:
            continue
        if m.models() and not counterparts(name, methods):
            want = "single" if m.kind == "knn" and m.shortlist == "s1" else \
                "smoothing or delta" if m.kind == "knn" else f"raw+{m.matcher}"
            groups.setdefault(want, []).append(name)
            wants[name], below[name] = want.split(" or ")[-1], _below_single(name, m, methods)
    index = (results.get("config") or {}).get("index")
    if index and wants:
        return [without_index(results, wants)]
    return [f"{_and(names)} (add {want} to see whether the model{'s help' if len(names) > 1 else ' helps'}"
            f"{''.join(below[n] for n in names)})" for want, names in groups.items()]


def _and(names: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def without_index(results: Mapping[str, Any], wants: Mapping[str, str]) -> str:
    """What ``eval --index`` says of its learned methods without a counterpart (``wants``: method -> the model-free
    one): a map serves only its own methods, so the baseline runs on the dataset, without ``--index``."""
    cfg = results.get("config") or {}
    split = cfg.get("split")
    split = f" --split {split}" if split and split != "all" else ""
    command = (f"seqnet eval --dataset {cfg.get('dataset_path') or 'DS'}{split} "
               f"--method {','.join(dict.fromkeys(wants.values()))}")
    return (f"{', '.join(wants)} (map {cfg.get('index')} serves only its own methods; to see whether the model "
            f"helps, evaluate the model-free baseline without --index: {command})")


def _below_single(name: str, m: Any, methods: Mapping[str, Any]) -> str:
    """``; it is already below ...`` when a learned sequence descriptor scores below the raw single frame."""
    if m.kind != "knn" or m.shortlist == "s1" or "single" not in methods:
        return ""
    try:
        mine, single = float(methods[name]["recall@1"]), float(methods["single"]["recall@1"])
    except (KeyError, TypeError, ValueError):
        return ""
    return f"; it is already below the single-frame single: R@1 {mine:.3f} against {single:.3f}" if mine < single \
        else ""


def row_marks(notes: list[Note]) -> dict[str, str]:
    """What a results table adds to each flagged method's row."""
    return {n.learned: f"learned, below model-free {n.baseline}" for n in notes}


def note_entries(notes: Sequence[Note], evaluation: str | None = None) -> list[dict[str, Any]]:
    """``results.json``'s ``learned_below_baseline``: :meth:`Note.to_dict` of each of ``notes`` (of
    :func:`learned_below_baseline`; ``evaluation``: which of several evaluations they are about, added to each entry
    as ``evaluation``)."""
    return [{**n.to_dict(), **({"evaluation": evaluation} if evaluation else {})} for n in notes]
