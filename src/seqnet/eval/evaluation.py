"""What an evaluation returns (:class:`Evaluation`), and which items each method is evaluated on.

A single-frame method (:attr:`seqnet.methods.grammar.Method.single_frame`: ``single``, ``s1``) compares one
frame with one frame: it needs no window, so it queries and indexes every frame whatever L is. A
sequence method queries and indexes the frames whose L- and L_m-windows fit inside their sequence.
Methods are grouped by the :class:`~seqnet.sequence.windows.Windows` they need
(:func:`method_windows`); each group is ranked and scored on its own items, and each method's items
are its :class:`ItemView` (:meth:`Evaluation.view`). The evaluation's own ``truth``, ``q_items``,
``r_items`` and names are those of the sequence methods (of the only group when every method shares
it), so a run whose methods all share the windows is what it always was.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..methods.grammar import Method
from ..metrics.recall import GroundTruth
from ..sequence.windows import Windows, window_offset

if TYPE_CHECKING:
    from ..data.traverse import Dataset


@dataclasses.dataclass(frozen=True)
class ItemView:
    """The items one method was evaluated on.

    Attributes:
        truth: what is correct for each of its query items.
        q_items: ``[M]`` query frame of each evaluated query; r_items: ``[R]`` reference frame of each indexed
            reference (its rankings index these).
        query_names, reference_names: ``[M]``, ``[R]`` image names of those frames, when known.
        windows: the windows the items are the frames of (L = L_m = 1 for a single-frame method).
    """

    truth: GroundTruth
    q_items: np.ndarray
    r_items: np.ndarray
    query_names: list[str] | None = None
    reference_names: list[str] | None = None
    windows: Windows | None = None


@dataclasses.dataclass
class Evaluation:
    """Results of :func:`seqnet.eval.evaluate.evaluate`: JSON-ready ``results`` plus rankings for plots.

    ``truth``, ``q_items``, ``r_items`` and the names are the sequence methods' items (see the module); a
    method evaluated on other items (a single-frame method beside sequence methods) has its own
    :class:`ItemView` in ``views``: read every method's items through :meth:`view`.
    """

    results: dict[str, Any]
    retrieved: dict[str, np.ndarray]  # method -> [M, K] indices into its r_items, best first
    scores: dict[str, np.ndarray]  # method -> [M, K] scores of ``retrieved`` (lower is better)
    truth: GroundTruth  # what is correct for each query item (radius or explicit positives)
    q_items: np.ndarray  # [M] query frame of each evaluated query
    r_items: np.ndarray  # [R] reference frame of each indexed reference
    confidence: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)  # method -> [M] in [0, 1]
    query_names: list[str] | None = None  # [M] image names of the evaluated queries, when known
    reference_names: list[str] | None = None  # [R] image names of the reference items, when known
    dataset: Dataset | None = None  # what was evaluated (the split, re-sampled as asked), for the report
    matrix: np.ndarray | None = None  # [Nq, Nr] given distances of ``dataset``'s frames (eval --distances)
    views: dict[str, ItemView] = dataclasses.field(default_factory=dict)  # method -> its items, when not the above
    windows: Windows | None = None  # the windows of ``q_items`` / ``r_items``
    frame_names: tuple[list[str] | None, list[str] | None] = (None, None)  # every query / reference frame's name
    # each query / reference frame's number in the split before --resample-every (None: not re-sampled)
    frame_numbers: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def frame_number(self, side: int, frames: np.ndarray) -> np.ndarray:
        """``frames [N]`` of the evaluated query (``side`` 0) or reference (1) traverse as the user numbers them:
        the split's frame numbers before re-sampling (-1 stays -1)."""
        numbers = self.frame_numbers[side]
        frames = np.asarray(frames, dtype=np.int64)
        return frames if numbers is None else np.where(frames >= 0, numbers[np.maximum(frames, 0)], -1)

    def view(self, method: str) -> ItemView:
        """The items ``method`` was evaluated on (its own view, else the evaluation's)."""
        if method in self.views:
            return self.views[method]
        return ItemView(self.truth, self.q_items, self.r_items, self.query_names, self.reference_names, self.windows)

    def __repr__(self) -> str:
        """One line: the dataset, split and each method's R@1 over its queries (``results`` holds the rest)."""
        cfg = self.results.get("config") or {}
        said = ", ".join(f"{name} R@1 {r['recall@1']:.3f} ({r.get('queries')} queries)" if
                         isinstance(r.get("recall@1"), float) else f"{name} ({r.get('queries')} queries)"
                         for name, r in (self.results.get("methods") or {}).items())
        return (f"Evaluation(dataset {cfg.get('dataset')!r}, split {cfg.get('split')!r}: {said}; "
                f"{len(self.results.get('warnings', []))} warnings; .results holds the rest)")

    @property
    def q_pos(self) -> np.ndarray:
        """``[M, P]`` positions of the evaluated query frames."""
        return self.truth.q_pos

    @property
    def r_pos(self) -> np.ndarray:
        """``[R, P]`` positions of the indexed reference frames."""
        return self.truth.r_pos

    @property
    def radius(self) -> float:
        """The localisation radius."""
        return self.truth.radius


def single_windows(windows: Windows) -> Windows:
    """The windows of a single-frame method: one frame (L = L_m = 1), same mode and anchor."""
    return Windows(1, 1, windows.mode, windows.anchor)


def method_windows(methods: Sequence[Method], windows: Windows, common: bool = False) -> dict[Windows, list[Method]]:
    """The methods grouped by the windows they are evaluated on, sequence methods' group first: ``windows``,
    or one frame for a single-frame method (``common``: every method on ``windows``, one query set)."""
    groups: dict[Windows, list[Method]] = {windows: []}  # the sequence group first; methods in the order given
    for m in methods:
        groups.setdefault(single_windows(windows) if m.single_frame and not common else windows, []).append(m)
    return {w: ms for w, ms in groups.items() if ms}


def no_window_reason(windows: Windows, bounded: bool = True) -> str:
    """Why frames have no query or reference item under ``windows`` (their windows do not fit their sequence):
    ``bounded``, the frames carry sequence bounds; else the only ends are those of the frames evaluated (the
    traverse, or the split's range, which cuts windows as well)."""
    n = windows.longest
    lens = f"L={windows.seq_len}" + (f", L_m={windows.match_len}" if windows.match_len != windows.seq_len else "")
    if windows.mode == "centred":
        head, tail = window_offset(n, "centred"), n - 1 - window_offset(n, "centred")
        where = "each sequence" if bounded else "the evaluated range"
        ends = f"{_frames(head)} of {where}'s start or end" if head == tail else \
            f"{_frames(head)} of {where}'s start or {tail} of its end"
        return f"windows of {n} centred frames ({lens}) do not fit within {ends}"
    where = "each sequence" if bounded else "the evaluated range"
    return f"causal windows of {n} frames ({lens}) do not fit in the first {_frames(n - 1)} of {where}"


def _frames(n: int) -> str:
    return f"{n} frame" + ("" if n == 1 else "s")


def merge(parts: Sequence[Evaluation], order: Sequence[str]) -> Evaluation:
    """One evaluation of the groups' ``parts`` (the first: the sequence methods', whose items are the
    evaluation's), methods in ``order``; each method keeps its own :class:`ItemView`."""
    main = parts[0]
    if len(parts) == 1:
        return main
    out = dataclasses.replace(main, results={**main.results, "methods": {}}, retrieved={}, scores={}, confidence={},
                              views={})
    for p in parts:
        for name in p.retrieved:
            out.views[name] = p.view(name)
    for name in order:
        p = next(p for p in parts if name in p.retrieved)
        out.results["methods"][name] = p.results["methods"][name]
        out.retrieved[name], out.scores[name] = p.retrieved[name], p.scores[name]
        if name in p.confidence:
            out.confidence[name] = p.confidence[name]
    return out


def descriptor_record(ds: Dataset) -> dict[str, dict[str, Any]]:
    """Which descriptors each side of ``ds`` holds (``{"reference": ..., "query": ...}``): ``kind`` (``describe``,
    ``synthetic``, ``external`` ...), ``method``, ``views``, image ``size``, ``pca`` (the dimensions a PCA reduced
    to, None without one), ``dim`` (D) and ``provenance`` (its id, :mod:`seqnet.core.provenance`). Read from each
    traverse's provenance, else from the dataset's ``describe`` and ``pca`` records (``dataset.json``); None where
    neither says."""
    described, pca = (ds.extra.get(k) if isinstance(ds.extra.get(k), Mapping) else {} for k in ("describe", "pca"))
    return {side: side_record(getattr(ds, side).provenance, getattr(ds, side).dim, described, pca)
            for side in ("reference", "query")}


def side_record(provenance: Any, dim: int, described: Mapping[str, Any] | None = None,
                pca: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One side of :func:`descriptor_record`: descriptors of ``dim`` D and ``provenance`` (a dict or None), else
    ``described`` / ``pca`` (the dataset's records)."""
    described, pca = described or {}, pca or {}
    prov = provenance if isinstance(provenance, Mapping) else {}
    settings = prov.get("settings") if isinstance(prov.get("settings"), Mapping) else {}
    known = settings if settings.get("method") else described
    method = known.get("method")
    return {"kind": prov.get("kind"), "method": method,
            "views": list(known.get("views") or ["raw"]) if method else None, "size": known.get("size"),
            "pca": settings.get("dim") if "pca_on" in settings else pca.get("dims"), "dim": int(dim),
            "provenance": prov.get("id")}
