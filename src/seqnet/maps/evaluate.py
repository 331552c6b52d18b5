"""``seqnet eval --index MAP``: a dataset's query split against a prebuilt map.

Only the query side of the dataset is read and described; the reference side is the map's
(shortlist through its index, re-ranking on its memory-mapped frames). Methods: the map's HVPR
(``hvpr`` or ``hvpr-<shortlist>:<frames>+<matcher>``), its shortlister alone (k-NN through the
index) and its whole-map matcher (``<frames>+<matcher>``, streamed over the map). Each HVPR and
k-NN entry reports ``shortlist_recall@K``: the fraction of the exact top-K (by the stored shortlist
descriptors) that the index returns.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.stage import Written
from ..data.io import POSITIVES_FILE, load_positives, load_traverse
from ..data.positives import Positives
from ..data.traverse import Traverse, default_split
from ..eval.evaluate import EvalConfig, Evaluation
from ..eval.evaluation import merge, method_windows, side_record
from ..eval.notices import add_warnings, radius_ignored, shift_notice, split_note, trivial_ks
from ..eval.outputs import EvalOutputs
from ..eval.runner import run
from ..methods.grammar import Method, parse_method
from ..metrics.recall import ground_truth
from ..report.guidance import learned_below_baseline, note_entries
from ..search.ann import shortlist_recall
from .load import load_map
from .map import Map


@dataclasses.dataclass
class QueryData:
    """The query side of one split of a dataset directory (the reference side is never read)."""

    traverse: Traverse
    split: str
    radius: float
    name: str
    query_range: tuple[int, int]
    root: Path
    unit: str = "metres"  # of the positions: "frames" (frame numbers), "metres", ...
    note: str | None = None  # what is scored when no split was given and none is named test
    ref_dir: Path | None = None  # the dataset's reference traverse folder
    records: dict[str, Any] = dataclasses.field(default_factory=dict)  # dataset.json's describe and pca records


def load_query(dataset: str | Path, split: str | None = None) -> QueryData:
    """Read ``dataset.json`` and the query traverse of ``split`` (None: test when defined, else all)."""
    root = Path(dataset)
    try:
        meta = json.loads((root / "dataset.json").read_text(encoding="utf-8"))
        radius = float(meta["radius"])
    except FileNotFoundError as err:
        raise DatasetError(f"{root} is not a seqnet dataset: dataset.json is missing") from err
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
        raise DatasetError(f"{root / 'dataset.json'}: not a dataset description with a radius ({e})") from e
    t = load_traverse(root / (meta.get("traverses") or {}).get("query", "query"), "query")
    t.provenance = (meta.get("provenance") or {}).get("query")
    splits = meta.get("splits") or {}
    given, split = split, default_split(split, splits)
    rng = (0, len(t))
    if split != "all":
        if split not in splits:
            raise DatasetError(f"dataset {root} has no split {split!r}; valid: {', '.join(['all', *splits])}")
        raw = splits[split]["query"] if isinstance(splits[split], dict) else splits[split]
        rng = (int(raw[0]), int(raw[1]))
        t = t.subset(*rng)
    name = str(meta.get("name", root.name))
    unit = meta.get("position_unit") or ("frames" if t.positions.shape[1] == 1 else "metres")
    note = split_note(given, list(splits), len(t))
    ref_dir = root / (meta.get("traverses") or {}).get("reference", "reference")
    records = {k: meta[k] for k in ("describe", "pca") if isinstance(meta.get(k), dict)}
    return QueryData(t, split, radius, name if split == "all" else f"{name}[{split}]", rng, root, str(unit), note,
                     ref_dir, records)


def check_source(mp: Map, q: QueryData) -> None:
    """Refuse a map built from another dataset when the positions are frame numbers: frame numbers of two
    datasets name unrelated places (positions in metres, e.g. UTM, of another traverse of the same area are
    comparable: such a map is evaluated)."""
    src = mp.meta.get("source") or {}
    if src.get("dataset_path") in (None, str(q.root.resolve())) or (q.root / POSITIVES_FILE).is_file():
        return  # the same dataset, or explicit positives (refused by :func:`_positives` unless the same split)
    units = (q.unit, src.get("position_unit") or "metres")
    if "frames" in units and not _same_reference(mp, q):
        said = {"frames": "frame numbers", "metres": "metres"}
        give = (f"dataset {q.root} and map {mp.path} give positions as frame numbers" if len(set(units)) == 1 else
                f"dataset {q.root} gives positions as {said.get(units[0], units[0])} and map {mp.path} as "
                f"{said.get(units[1], units[1])}")
        why = "frame numbers of two datasets" if len(set(units)) == 1 else "frame numbers and metres"
        raise ConfigError(f"{give}, but the map was built from {src.get('dataset_path')} [{src.get('split')}]: "
                          f"{why} do not name the same places; hint: build the map from this dataset and split")


def _same_reference(mp: Map, q: QueryData) -> bool:
    """Whether the dataset's reference (over the map's reference range) has the map's names and positions: the
    same dataset, moved or copied since the map was built."""
    try:
        ref = load_traverse(q.ref_dir, "reference") if q.ref_dir is not None else None
        a, b = (mp.meta.get("source") or {}).get("reference_range") or (0, 0)
    except DatasetError:
        return False
    if ref is None or not 0 <= a < b <= len(ref) or b - a != len(mp.positions):
        return False
    names_ok = ref.names is None or mp.names is None or list(ref.names[a:b]) == list(mp.names)
    pos = np.asarray(ref.positions[a:b])
    return names_ok and pos.shape == mp.positions.shape and bool(np.array_equal(pos, mp.positions))


def _positives(mp: Map, q: QueryData, q_items: np.ndarray, r_frames: np.ndarray | None = None) -> Positives | None:
    """Explicit positives of the dataset over the map's items (``r_frames``: those map frames instead; only for a map
    built from this dataset and split)."""
    if not (q.root / POSITIVES_FILE).is_file():
        return None
    src = mp.meta.get("source") or {}
    if src.get("dataset_path") != str(q.root.resolve()) or src.get("split") != q.split:
        raise ConfigError(f"dataset {q.root} defines explicit positives over its own reference frames, but map "
                          f"{mp.path} was built from {src.get('dataset_path')} [{src.get('split')}]; hint: build "
                          "the map from this dataset and split")
    ra = int(src["reference_range"][0])
    return load_positives(q.root / POSITIVES_FILE).select(q.query_range[0] + q_items,
                                                           ra + (mp.items if r_frames is None else r_frames))


def check_conf(mp: Map, conf: EvalConfig) -> list[Method]:
    """The methods of ``conf`` the map serves; refuses another L, L_m, window mode or method."""
    c, w = mp.config, mp.config.windows
    for key, want, have in (("seq_len", conf.seq_len, w.seq_len), ("match_len", conf.match_len, w.match_len)):
        if want is not None and want != have:
            raise ConfigError(f"{key}={want} but map {mp.path} was built with {have}; rebuild the map to change it")
    if conf.window != c.window:
        raise ConfigError(f"window {conf.window!r} but map {mp.path} uses {c.window!r} windows (hint: --window "
                          f"{c.window}, the map's; --window {conf.window} needs a map built with it)")
    if conf.resample_every is not None:
        raise ConfigError(f"map {mp.path} holds its reference as built; re-sample the dataset first (seqnet dataset "
                          "resample --every N) and evaluate it, or build a map from the re-sampled dataset")
    methods = [parse_method(n) for n in conf.methods or [c.method.name, c.method.shortlist]]
    for m in methods:
        mp.check_method(m)
    return methods


def _shortlist_recall(mp: Map, q_short: np.ndarray, top_k: int) -> Callable[[Method, np.ndarray], dict[str, Any]]:
    """``shortlist_recall@K`` of the k-NN and HVPR entries: the fraction of the exact top-K that the index returns."""
    exact = mp.search(mp.config.shortlist, q_short, top_k, exact=True)[1] if mp.index is not None else None

    def extra(m: Method, retrieved: np.ndarray) -> dict[str, Any]:
        if m.kind == "match":
            return {}
        head = min(top_k, retrieved.shape[1])
        if exact is None:
            return {f"shortlist_recall@{head}": 1.0}  # flat: the exact search itself
        # the head of a ranking is the shortlist's head (HVPR only re-orders it)
        return {f"shortlist_recall@{head}": round(shortlist_recall(retrieved[:, :head], exact[:, :head]), 4)}

    return extra


def evaluate_map(mp: Map, q: QueryData, conf: EvalConfig | None = None) -> Evaluation:
    """Evaluate the query side ``q`` against the map ``mp`` (methods: :meth:`Map.served`): the
    evaluation loop of :func:`seqnet.eval.runner.run` with the map as the reference, a single-frame method on every
    frame of both sides (:meth:`Map.for_method`), as ``seqnet eval`` scores it."""
    conf = conf or EvalConfig()
    methods = check_conf(mp, conf)
    mp.check_query(q.traverse.dim, q.traverse.provenance, conf.allow_mismatch)
    check_source(mp, q)
    c = mp.config
    conf = conf.merge(seq_len=c.windows.seq_len, match_len=c.windows.match_len, radius=conf.radius or q.radius)
    groups = method_windows(methods, mp.windows, conf.common_queries)
    ev = merge([_evaluate_group(mp, mp if w == mp.windows else mp.for_method(ms[0]), q, ms, conf)
                for w, ms in groups.items()], [m.name for m in methods])
    positives = (q.root / POSITIVES_FILE).is_file()
    ev.results["config"] = {**conf.to_dict(), "methods": [m.name for m in methods], "split": q.split,
                            "query_range": list(q.query_range),  # the per-query files' numbering (VME)
                            "dataset": q.name, "device": str(mp.device), "index": str(mp.path),
                            "map": mp.meta["config"],
                            "ground_truth": "explicit positives" if positives else "radius"}
    same = (mp.meta.get("source") or {}).get("dataset_path") in (None, str(q.root.resolve()))
    if same and (mp.meta.get("source") or {}).get("reference_range"):  # --per-query: the dataset's reference rows
        ev.results["config"]["reference_range"] = list(mp.meta["source"]["reference_range"])
    ref_records = q.records if same else {}  # the map's own dataset's records are not read
    ev.results["descriptors"] = {  # as seqnet eval's (eval.evaluation.descriptor_record): the dataset's records too
        "reference": side_record(mp.provenance, mp.input_dim, ref_records.get("describe"), ref_records.get("pca")),
        "query": side_record(q.traverse.provenance, q.traverse.dim, q.records.get("describe"), q.records.get("pca"))}
    ev.frame_names = (q.traverse.names, mp.names)
    return ev


def _evaluate_group(mp: Map, ref: Map, q: QueryData, methods: list[Method], conf: EvalConfig) -> Evaluation:
    """The ``methods`` that search ``ref`` (the map, or its view of every frame for a single-frame method), on its
    windows' query items."""
    query = ref.describe(q.traverse)
    items = query.side.items
    positives = _positives(ref, q, items)
    # a query correct only at frames without a window counts, as a failure: its explicit positives over every frame
    every = _positives(ref, q, items, np.arange(len(ref.positions))) if len(ref.items) < len(ref.positions) else None
    truth = ground_truth(q.traverse.positions[items], ref.positions[ref.items], conf.radius, positives,
                         f"{q.name} against map {mp.path}", q.unit, frames=ref.positions,
                         matched=None if every is None else every.counts() > 0)
    c = mp.config

    def info(m: Method) -> dict[str, Any]:
        return {**m.summary(), "seq_len": c.windows.seq_len, "match_len": c.windows.match_len,
                "top_k": conf.shortlist_size(m), "index": c.ann.kind}

    extra = _shortlist_recall(ref, query.items(c.shortlist), conf.shortlist_size(c.method))
    ev = run(methods, query, ref, truth, conf, len(q.traverse), info, extra,
             windows=None if ref is mp else ref.windows)
    ev.query_names = [q.traverse.names[i] for i in items] if q.traverse.names else None
    ev.reference_names = [ref.names[i] for i in ref.items] if ref.names else None
    return ev


def main(conf: EvalConfig, dataset: str | Path, index: str | Path, out: str | Path | None,
         per_query: str | Path | None = None, figures: bool = False, overwrite: bool = False,
         json: str | Path | None = None, report: Any = None, free: Sequence[str] = ()) -> Written:
    """hloc-style stage: evaluate ``conf.split`` of the dataset's queries against the map ``index``;
    writes ``out/results.json`` and what ``per_query``, ``figures`` (``out/pr_curve.png``), ``report`` (a
    :class:`seqnet.report.html.ReportConfig`: ``out/report.html``, without the sections that read the reference
    side as a dataset) and ``json`` ask, as one set (:class:`seqnet.eval.outputs.EvalOutputs`); returns the
    results path and the results. The map's HVPR settings chosen on val when it was built
    (:mod:`seqnet.maps.chosen`) replace those of ``free`` (the settings the caller left free: ``seqnet eval --index``
    passes the flags not given; empty, the API's default: ``conf`` as given); the results' ``"selection"`` says
    which were used."""
    outputs = EvalOutputs(out, per_query, json, figures, report, overwrite)
    with outputs.session(conf.methods):  # a second evaluation into the same folder is refused (exit 1)
        mp = load_map(index, conf.device)
        outputs.check_methods([m.name for m in check_conf(mp, conf)])
        conf, selection = with_map_settings(mp, conf, free)
        q = load_query(dataset, conf.split)
        ev = evaluate_map(mp, q, conf)
        if selection:
            ev.results["selection"] = selection
        ev.results["config"]["dataset_path"] = str(dataset)
        explicit = ev.results["config"]["ground_truth"] == "explicit positives"
        add_warnings(ev, [q.note, shift_notice(ev), radius_ignored(conf.radius, explicit), trivial_ks(ev, conf.ks)])
        ev.results["learned_below_baseline"] = note_entries(learned_below_baseline(ev.results))
        ev.results["inputs"] = {"dataset": str(Path(dataset).resolve()), "index": str(Path(index).resolve())}
        return outputs.write(ev)


def with_map_settings(mp: Map, conf: EvalConfig, free: Sequence[str]) -> tuple[EvalConfig, dict[str, Any] | None]:
    """``conf`` with the map's stored HVPR settings (:func:`seqnet.maps.chosen.settings_to_use`) for its method,
    where ``free`` (names of ``top_k``, ``fuse_top_k``, ``fuse_weight``) leaves them free, and the results'
    ``"selection"`` (its ``hvpr`` choices; ``not_chosen``: the flags that won or why
    none is stored); None for a map without the record."""
    from .chosen import FLAGS, settings_to_use

    method = mp.config.method
    given = {k: None if k in free else getattr(conf, k) for k in FLAGS}
    use, line = settings_to_use(mp.meta, method.name, given)
    if line is None:
        return conf, None
    if "fuse_weight" in use:
        conf = conf.merge(method_fuse_weight={**(conf.method_fuse_weight or {}), method.name: use["fuse_weight"]})
    k = use.get("top_k", use.get("fuse_top_k"))
    if k is not None:
        conf = conf.merge(method_top_k={**(conf.method_top_k or {}), method.name: k})
    rec = mp.meta["selection"]
    chosen = [c for c in rec.get("hvpr") or [] if isinstance(c, dict)] if use else []
    return conf, {"hvpr": [{**c, "reason": line} for c in chosen[:1]], "from_map": True,
                  **({} if chosen else {"not_chosen": line})}
