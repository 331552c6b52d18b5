"""What an evaluation reports for each method: Recall@K, precision–recall with confidence, and
per-query rows (ranked references, scores, correct or not) for a CSV or JSONL file."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.files import write_text_atomic
from .metrics.precision_recall import (
    curve_points,
    pr_summary,
    precision_recall,
    ratio_confidence,
    thresholds_for,
)
from .metrics.recall import GroundTruth, recall

PER_QUERY_FORMATS = (".csv", ".jsonl", ".txt")  # .txt: MSLS's predictions format (one method)
MSLS_TOP = 20  # predictions per query in an MSLS file (its evaluation reads up to 20)


def method_results(scores: np.ndarray, ranked: np.ndarray, truth: GroundTruth, ks: Sequence[int],
                   extra_radii: Sequence[float] = (), denominator: str = "positives") -> tuple[dict[str, Any],
                                                                                           np.ndarray]:
    """The results entry of one method (Recall@K over the ``denominator`` queries, queries, AUC, R@100P, the
    PR curve ``pr_curve`` (at most 200 of its points), extra radii) and its ``[M]`` per-query confidence (see
    :mod:`seqnet.eval.metrics.precision_recall`)."""
    rec = recall(ranked, truth, ks, denominator)
    entry: dict[str, Any] = {k: v for k, v in rec.items() if k.startswith("recall@")}
    entry.update(queries=rec["queries"], no_positive=rec["no_positive"], recall_denominator=denominator)
    confidence = ratio_confidence(scores, ranked, truth.r_pos, truth.radius)
    correct = truth.hits(ranked[:, :1])[:, 0] if ranked.shape[1] else np.zeros(len(ranked), bool)
    precision, rec, thresholds = precision_recall(confidence, correct, truth.has_positive())
    entry.update(pr_summary(precision, rec), pr_curve=curve_points(precision, rec),
                 confidence_for_precision=thresholds_for(precision, rec, thresholds))
    if extra_radii:
        entry["radii"] = {str(r): recall(ranked, GroundTruth(truth.q_pos, truth.r_pos, r), ks, denominator)
                          for r in extra_radii}
    return entry, confidence


def per_query_rows(ev: Any, top: int = 5) -> list[dict[str, Any]]:
    """One row per (method, query): query frame and name, top-``top`` reference frames and scores,
    whether each is correct, whether the query has a correct reference, and the confidence."""
    q_names = ev.query_names
    r_frames = ev.r_items
    rows = []
    for name, ranked in ev.retrieved.items():
        head = ranked[:, :top]
        hits = ev.truth.hits(head)
        has = ev.truth.has_positive()
        for m, q in enumerate(ev.q_items):
            refs = [int(r_frames[j]) if j >= 0 else -1 for j in head[m]]
            rows.append({"method": name, "query_frame": int(q), "query_name": q_names[m] if q_names else "",
                         "references": refs, "scores": [_num(s) for s in ev.scores[name][m, :top]],
                         "correct": [bool(h) for h in hits[m]], "has_positive": bool(has[m]),
                         "confidence": round(float(ev.confidence[name][m]), 6)})
    return rows


def msls_predictions(ev: Any) -> str:
    """MSLS's predictions file (mapillary_sls ``evaluate.py``): one line per query, its key then the keys of
    its top-20 references, best first; a key is an image name's basename without its extension. One
    method only (the file cannot say which), and the names must be known."""
    if len(ev.retrieved) != 1:
        raise ConfigError(f"an MSLS predictions file holds one method, got {len(ev.retrieved)} "
                          f"({', '.join(ev.retrieved)}); hint: --method M")
    if ev.query_names is None or ev.reference_names is None:
        raise ConfigError("an MSLS predictions file needs image names for the query and reference images")
    key = [Path(n).stem for n in ev.reference_names]
    ranked = next(iter(ev.retrieved.values()))[:, :MSLS_TOP]
    return "".join(" ".join([Path(q).stem, *(key[j] for j in row if j >= 0)]) + "\n"
                   for q, row in zip(ev.query_names, ranked, strict=True))


def _num(x: float) -> float | None:
    return round(float(x), 6) if np.isfinite(x) else None


def write_per_query(ev: Any, path: str | Path, top: int = 5) -> Path:
    """Write :func:`per_query_rows` to ``path``: ``.csv`` (lists joined by ``;``) or ``.jsonl``; or ``.txt``,
    MSLS's predictions format (:func:`msls_predictions`)."""
    path = Path(path)
    if path.suffix.lower() not in PER_QUERY_FORMATS:
        raise ConfigError(f"per-query file {path} must end in {' or '.join(PER_QUERY_FORMATS)}")
    if path.suffix.lower() == ".txt":
        return write_text_atomic(path, msls_predictions(ev))
    rows = per_query_rows(ev, top)
    if path.suffix.lower() == ".jsonl":
        return write_text_atomic(path, "".join(json.dumps(r, allow_nan=False) + "\n" for r in rows))
    buf = io.StringIO()
    fields = ["method", "query_frame", "query_name", "references", "scores", "correct", "has_positive", "confidence"]
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ";".join("" if x is None else str(x) for x in v) if isinstance(v, list) else v
                         for k, v in r.items()})
    return write_text_atomic(path, buf.getvalue())
