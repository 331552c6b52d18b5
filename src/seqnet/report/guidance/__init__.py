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
from pathlib import Path
from typing import Any

from ...core.errors import ConfigError
from ...methods.grammar import parse_method
from .causes import (  # noqa: F401 - guidance names, used by eval, the cli and the tests
    barely_trained,
    likely_causes,
    model_entries,
    one_query,
    training_record,
    within_chance,
)

SEQUENCE_BASELINES = ("smoothing", "delta", "delta-paper")


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
        return f"{self.finding()} {self.compared()}; likely: {'; '.join(self.causes)}"

    def compared(self) -> str:
        """What the two were compared on: the same data, or the same queries of the unreduced descriptors."""
        return "on the same queries" if " on the unreduced " in self.baseline else "on the same data"

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


def learned_below_baseline(results: Mapping[str, Any]) -> list[Note]:
    """One :class:`Note` per learned method of ``results`` whose R@1 is below the best of its model-free
    counterparts by at least one query (``1 / queries``; 0.001 when the count is unknown): those evaluated beside
    it and, on a dataset that ``--pca`` reduced, the same on the unreduced descriptors (their entries' ``unreduced``:
    :func:`seqnet.eval.notices.unreduced.unreduced_counterparts`), whose loss to the PCA is then named first."""
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
        below = best - float(r1) >= one_query(entry.get("queries")) - 1e-9
        pca = unreduced_best(results, name, key, best)
        if pca is not None and pca[0] - float(r1) >= one_query(entry.get("queries")) - 1e-9:
            causes = likely_causes(name, results, (float(r1), pca[0]), explained=not below, k=k)
            notes.append(Note(name, pca[1], float(r1), pca[0], (pca[2], *causes), k))
        elif below:
            notes.append(Note(name, base, float(r1), best, likely_causes(name, results, (float(r1), best), k=k), k))
    return notes


def unreduced_best(results: Mapping[str, Any], name: str, key: str, best: float) -> tuple[float, str, str] | None:
    """``(its recall, the counterpart's label, the PCA's cost said as a cause)`` of the best model-free counterpart
    of ``name`` on the unreduced descriptors (the counterpart's entry's ``unreduced``, scored on as many queries),
    when it is above ``best`` (the best evaluated beside it) by a query or more; else None."""
    methods = results.get("methods", {})
    there = {b: methods[b]["unreduced"] for b in counterparts(name, methods)
             if isinstance(methods[b].get("unreduced"), Mapping)}
    scored = [(float(u[key]), b) for b, u in there.items()
              if isinstance(u.get(key), float) and u.get("queries") == methods[b].get("queries")]
    if not scored or max(scored)[0] - best < one_query(methods[name].get("queries")) - 1e-9:
        return None
    r, b = max(scored)
    free = there[b]
    where = Path(str(free.get("dataset"))).name
    dims = free.get("dims") if isinstance(free.get("dims"), list) and len(free["dims"]) == 2 else ["D", "D'"]
    cause = (f"the PCA ({dims[0]} -> {dims[1]} dims) alone cost {b} R@{key.split('@')[1]} {r:.3f} -> "
             f"{float(methods[b][key]):.3f} on these queries ({where} holds the unreduced descriptors); hint: compare "
             f"with a model "
             f"trained on {where} itself (seqnet train --dataset {free.get('dataset')}, without --pca), or keep more "
             "dimensions (--pca D)")
    return r, f"{b} on the unreduced {where}", cause


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
        groups.setdefault((*n.causes, n.compared()), []).append(n)
    return [f"note: {'; '.join(n.finding() for n in group)} {group[0].compared()}; likely: {'; '.join(causes)}"
            for (*causes, _), group in groups.items()]


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
