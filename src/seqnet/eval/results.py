"""What an evaluation reports for each method: Recall@K, precision–recall with confidence, and
per-query rows (ranked references, scores, correct or not) for a CSV or JSONL file."""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, OutputError
from ..metrics.consistency import QueryOrder, sequence_confidence
from ..metrics.precision_recall import (
    curve_points,
    pr_summary,
    precision_recall,
    ratio_confidence,
    thresholds_for,
)
from ..metrics.recall import GroundTruth, recall
from ..security.files import write_text_atomic
from ..security.inputs import open_input
from ..security.text import csv_cell
from .msls_predictions import MSLS_MARK, msls_predictions


def method_results(scores: np.ndarray, ranked: np.ndarray, truth: GroundTruth, ks: Sequence[int],
                   extra_radii: Sequence[float] = (), denominator: str = "positives",
                   order: QueryOrder | None = None) -> tuple[dict[str, Any], np.ndarray]:
    """The results entry of one method (Recall@K over the ``denominator`` queries, queries, AUC, R@100P, the
    PR curve ``pr_curve`` (at most 200 of its points), extra radii) and its ``[M]`` per-query confidence (the
    ratio confidence of :mod:`seqnet.metrics.precision_recall`; with ``order``, the sequence confidence of
    :mod:`seqnet.metrics.consistency`). With one reference retrieved per query (``--ks 1``) the confidence has no
    other place to compare with: the PR entries are left empty (AUC and R@100P None, no thresholds)."""
    rec = recall(ranked, truth, ks, denominator)
    entry: dict[str, Any] = {k: v for k, v in rec.items() if k.startswith("recall@")}
    entry.update(queries=rec["queries"], no_positive=rec["no_positive"], recall_denominator=denominator)
    if rec.get("positive_not_indexed"):  # correct references only where no full window fits: failures
        entry["positive_not_indexed"] = rec["positive_not_indexed"]
    confidence, correct = top1_confidence(scores, ranked, truth, order)
    scored = slice(None) if ranked.shape[1] >= 2 else slice(0)  # one retrieved: no other place to compare with
    precision, rec, thresholds = precision_recall(confidence[scored], correct[scored], truth.has_positive())
    entry.update(pr_summary(precision, rec), pr_curve=curve_points(precision, rec),
                 confidence_for_precision=thresholds_for(precision, rec, thresholds))
    if not len(precision):  # nothing to summarise: null in results.json (NaN is not JSON)
        entry.update({"auc": None, "recall@100p": None})
    if extra_radii:
        entry["radii"] = {str(r): {k: None if isinstance(v, float) and np.isnan(v) else v  # no query within r: null
                                   for k, v in recall(ranked, truth.within(r), ks, denominator).items()}
                          for r in extra_radii}
    return entry, confidence


def top1_confidence(scores: np.ndarray, ranked: np.ndarray, truth: GroundTruth,
                    order: QueryOrder | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(confidence [M], correct [M])`` of each query's top-1 among its ranked ``scores`` / ``ranked [M, K]``:
    soft positives dropped first (neither true nor false positives in PR), confidence 0 when every retrieved was
    one; with ``order`` (where the items lie in their traverses), the sequence confidence of that top-1."""
    pr_ranked, pr_scores = truth.without_soft(ranked, scores)  # soft positives: neither TP nor FP in PR
    confidence = ratio_confidence(pr_scores, pr_ranked, truth.r_pos, truth.radius)
    confidence[pr_ranked[:, 0] < 0 if ranked.shape[1] else slice(0)] = 0.0  # every retrieved was a soft match
    correct = top1_correct(pr_ranked, truth)
    if order is not None:
        top = pr_ranked[:, 0] if ranked.shape[1] else np.full(len(ranked), -1)
        confidence = sequence_confidence(confidence, top, order)
    return confidence, correct


def top1_correct(ranked: np.ndarray, truth: GroundTruth) -> np.ndarray:
    """``[M]`` bool: each query's top-1 in ``ranked [M, K]`` (soft positives already dropped) is correct."""
    return truth.hits(ranked[:, :1])[:, 0] if ranked.shape[1] else np.zeros(len(ranked), bool)


def per_query_rows(ev: Any, top: int = 5) -> list[dict[str, Any]]:
    """One row per (method, query): the query's index and name, its top-``top`` references' indices, names and
    scores, whether each is correct, whether the query has a correct reference, and the confidence. An index is
    the frame's row in the dataset's whole query / reference list (``names.txt``), before a split and
    re-sampling (:func:`query_start`, :func:`reference_start`); -1 (and name "") is no reference; a name is ""
    when the dataset has none."""
    rows = []
    q0, r0 = query_start(ev), reference_start(ev)
    for name, ranked in ev.retrieved.items():
        view = ev.view(name)  # a single-frame method's items are every frame
        head = ranked[:, :top]
        hits = view.truth.hits(head)
        has = view.truth.has_positive()
        calibrated = ev.results["methods"].get(name, {}).get("calibrated")
        threshold = calibrated["calibration"]["threshold"] if calibrated else None
        q_rows = q0 + ev.frame_number(0, view.q_items)
        r_frames = ev.frame_number(1, np.where(head >= 0, view.r_items[np.maximum(head, 0)], -1))
        r_rows = np.where(r_frames >= 0, r0 + r_frames, -1)
        names = view.reference_names
        for m, q in enumerate(q_rows):
            rows.append({"method": name, "query_index": int(q),
                         "query_name": view.query_names[m] if view.query_names else "",
                         "reference_indices": [int(j) for j in r_rows[m]],
                         "reference_names": [names[j] if names and j >= 0 else "" for j in head[m]],
                         "scores": [_num(s) for s in ev.scores[name][m, :top]],
                         "correct": [bool(h) for h in hits[m]], "has_positive": bool(has[m]),
                         "confidence": round(float(ev.confidence[name][m]), 6),
                         **({"accepted": threshold is not None and bool(ev.confidence[name][m] >= threshold)}
                            if calibrated else {})})
    return rows


def _num(x: float) -> float | None:
    return round(float(x), 6) if np.isfinite(x) else None


def vpr_methods_predictions(ev: Any, top: int = 5) -> dict[str, str]:
    """VPR-methods-evaluation's saved predictions (``visualizations.save_preds``): per query a file
    ``<query index:03d>.txt`` holding ``Query path:``, the query, ``Predictions paths:``, its top-``top``
    references (best first) and ``Positives paths:``, every correct reference (image names as the dataset
    stores them). The index is the query's row in the whole query list, as VPR-methods-evaluation numbers
    it (``enumerate`` over its queries): a query left out of the evaluation keeps its number, and a split
    adds its first query (:func:`query_start`). One method only, and the names must be known."""
    if len(ev.retrieved) != 1:
        raise ConfigError(f"a VPR-methods-evaluation predictions folder holds one method, got {len(ev.retrieved)} "
                          f"({', '.join(ev.retrieved)}); hint: --method M")
    name, ranked = next(iter(ev.retrieved.items()))
    view = ev.view(name)
    if view.query_names is None or view.reference_names is None:
        raise ConfigError("a predictions folder needs image names for the query and reference images")
    refs = view.reference_names
    rows = query_start(ev) + ev.frame_number(0, view.q_items)  # [M] before re-sampling, in the whole query list
    out = {}
    for m, (q, row) in enumerate(zip(view.query_names, ranked[:, :top], strict=True)):
        parts = ["Query path:", q + "\n", "Predictions paths:", "\n".join(refs[j] for j in row if j >= 0) + "\n",
                 "Positives paths:", "\n".join(refs[j] for j in view.truth.of(m)) + "\n"]
        out[f"{int(rows[m]):03d}.txt"] = "\n".join(parts)
    return out


def query_start(ev: Any) -> int:
    """The evaluated split's first query frame in the dataset's whole query traverse (``results["config"]
    ["query_range"]``, which ``seqnet eval`` records); 0 when not recorded (an evaluation of a dataset as given)."""
    rng = ev.results.get("config", {}).get("query_range")
    return int(rng[0]) if rng else 0


def reference_start(ev: Any) -> int:
    """The evaluated split's first reference frame in the dataset's whole reference traverse (``results["config"]
    ["reference_range"]``, recorded with ``query_range``); 0 when not recorded."""
    rng = ev.results.get("config", {}).get("reference_range")
    return int(rng[0]) if rng else 0


def _write_folder(path: Path, files: dict[str, str]) -> Path:
    """A folder of per-query files, swapped in whole; an existing one is replaced only if seqnet wrote it."""
    from ..security.dirs import recover_dir, write_dir
    from ..security.locks import locked
    from ..security.ownership import check_replaceable, write_manifest

    def fill(tmp: Path) -> None:
        for name, text in files.items():
            write_text_atomic(tmp / name, text)
        write_manifest(tmp, "predictions", [tmp / n for n in files])

    with locked(path):
        recover_dir(path)
        check_replaceable(path, "predictions folder")  # seqnet's manifest, not file names: VME's own preds/ look alike
        return write_dir(path, fill)


CSV_FIELDS = ("method", "query_index", "query_name", "reference_indices", "reference_names", "scores", "correct",
              "has_positive", "confidence")
# seqnet's per-query columns before the indices were the dataset's (split-relative query_frame, references): a file
# with them is still seqnet's to replace, and an old reader of the renamed columns fails instead of misreading
OLD_CSV_FIELDS = ("method", "query_frame", "query_name", "references", "scores", "correct", "has_positive",
                  "confidence")
NAME_FIELDS = ("method", "query_name", "reference_names")  # text from the data: never a spreadsheet formula


def _rows_csv(rows: list[dict[str, Any]]) -> str:
    import csv  # only for a per-query CSV

    buf = io.StringIO()
    fields = (*CSV_FIELDS, "accepted") if rows and "accepted" in rows[0] else CSV_FIELDS  # with --target-precision
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ";".join(csv_cell(x) for x in v) if k == "reference_names" else
                         csv_cell(v) if k in NAME_FIELDS else
                         ";".join("" if x is None else str(x) for x in v) if isinstance(v, list) else
                         int(v) if k == "accepted" else v for k, v in r.items()})
    return buf.getvalue()


def _rows_jsonl(rows: list[dict[str, Any]]) -> str:
    return "".join(json.dumps(r, allow_nan=False) + "\n" for r in rows)


PER_QUERY_TEXTS = {  # by the file's extension ("": a folder of files)
    ".csv": lambda ev, top: _rows_csv(per_query_rows(ev, top)),
    ".jsonl": lambda ev, top: _rows_jsonl(per_query_rows(ev, top)),
    ".txt": lambda ev, top: msls_predictions(ev),
    "": vpr_methods_predictions,
}
PER_QUERY_FORMATS = tuple(PER_QUERY_TEXTS)


def per_query_format(path: str | Path) -> str:
    """The per-query format ``path`` names by its extension (a key of :data:`PER_QUERY_TEXTS`); refused when none."""
    fmt = Path(path).suffix.lower()
    if fmt not in PER_QUERY_TEXTS:
        raise ConfigError(f"per-query file {path} must end in .csv, .jsonl or .txt (MSLS), or have no extension "
                          "(a VPR-methods-evaluation predictions folder)")
    return fmt


def per_query_text(ev: Any, path: str | Path, top: int = 5) -> str | dict[str, str]:
    """The per-query results for ``path``, in the format its extension names: the text of a file, or the files
    (name: text) of a folder."""
    return PER_QUERY_TEXTS[per_query_format(path)](ev, top)


def write_per_query(ev: Any, path: str | Path, top: int = 5) -> Path:
    """Write the per-query results to ``path``, in the format its extension names (:data:`PER_QUERY_TEXTS`):
    :func:`per_query_rows` as ``.csv`` (lists joined by ``;``, names made safe for spreadsheets) or ``.jsonl``;
    ``.txt``, MSLS's predictions format (:func:`msls_predictions`); no extension, a VPR-methods-evaluation
    predictions folder (:func:`vpr_methods_predictions`). An existing output is replaced only when seqnet wrote
    it (:func:`check_per_query`; call it before the work)."""
    path = Path(path)
    out = per_query_text(ev, path, top)
    return _write_folder(path, out) if isinstance(out, dict) else write_text_atomic(path, out)


def check_per_query(path: str | Path, overwrite: bool = False) -> None:
    """Refuse (:class:`OutputError`) to replace an existing per-query output that seqnet did not write, unless
    ``overwrite``: a ``.csv`` is seqnet's when its first line is seqnet's header, a ``.jsonl`` when its first
    line is a row of seqnet's, an MSLS ``.txt`` when its first line is seqnet's ``# seqnet`` comment, a folder
    when its manifest says so (a folder of ``NNN.txt`` files without one may be VME's own ``preds/``)."""
    from ..security.ownership import check_replaceable

    path = Path(path)
    fmt = per_query_format(path)
    if overwrite or not (path.exists() or path.is_symlink()):
        return
    if fmt == "":
        if path.is_symlink():
            raise OutputError(f"{path} is a symbolic link; seqnet does not replace links (choose another --per-query)")
        return check_replaceable(path, "predictions folder")
    if not _our_rows(path, fmt):
        raise OutputError(f"{path} exists and was not written by seqnet eval (move it away, choose another "
                          "--per-query, or pass --overwrite)")


def _our_rows(path: Path, fmt: str) -> bool:
    """Whether the file ``path`` starts as seqnet's per-query ``.csv`` or ``.jsonl`` (a link or a special file
    never does)."""
    try:
        with open_input(path, "per-query file", OutputError, follow=False) as f:
            line = f.readline(1 << 16).decode("utf-8").rstrip("\n")
    except (OSError, OutputError, UnicodeDecodeError):
        return False
    if fmt == ".csv":
        return any(line in (",".join(f), ",".join((*f, "accepted"))) for f in (CSV_FIELDS, OLD_CSV_FIELDS))
    if fmt == ".txt":
        return line.startswith(MSLS_MARK)
    if fmt == ".jsonl":
        with contextlib.suppress(ValueError):
            row = json.loads(line)
            return isinstance(row, dict) and tuple(k for k in row if k != "accepted") in (CSV_FIELDS, OLD_CSV_FIELDS)
    return False
