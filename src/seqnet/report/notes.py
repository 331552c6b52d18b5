"""The report's sections beside the results table: what the evaluation warned of (:func:`warnings_section`), what
was chosen on val and why (:func:`choices_section`), the learned methods below their model-free counterparts
(:func:`notes_section`, :mod:`seqnet.report.guidance`), the Recall@K at each ``--extra-radius``
(:func:`radii_section`) and the calibrated confidence of ``--target-precision`` (:func:`calibration_section`)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

from ..data.sanity import ALIGNED_TRUTHS
from .guidance import learned_below_baseline
from .markup import Section, table_html


def truth_fact(cfg: Mapping[str, Any], ds: Any = None) -> tuple[str, str]:
    """The Summary's ground-truth row: explicit positives, or the radius in the dataset ``ds``'s position unit
    (``"1 frame"``, ``"25 metres"``), saying what it counts as correct (frame-aligned traverses: query frame i at
    reference frame i); the bare radius without a dataset (a map, a matrix)."""
    if cfg.get("ground_truth") == "explicit positives":
        return "ground truth", "explicit positives"
    radius, unit = cfg.get("radius", ""), getattr(ds, "position_unit", None)
    if not isinstance(radius, (int, float)) or not unit:
        return "radius", f"{radius:g}" if isinstance(radius, (int, float)) else str(radius)
    said = f"{radius:g} {unit[:-1] if radius == 1 and unit.endswith('s') else unit}"
    if (getattr(ds, "extra", None) or {}).get("ground_truth") in ALIGNED_TRUTHS:
        return "ground truth", (f"frame-aligned (query frame i shows the place of reference frame i): a reference "
                                f"within {said} of it is correct")
    return "radius", f"{said}: a reference at most this far from the query's position is correct"


def choices_section(results: Any) -> list[Section]:
    """A ``choices`` section saying what was chosen on val and why (the descriptor, HVPR's K and λ, or why
    nothing was; its warning unless the Warnings section says it already), with each grid; none when nothing was
    left to choose."""
    sel = results.get("selection") or {}
    picks = ([sel["descriptor"]] if isinstance(sel.get("descriptor"), dict) else []) + list(sel.get("hvpr") or [])
    items = [f"<li>{html.escape(str(c.get('reason', '')))}</li>" for c in picks]
    warned = {str(w) for key in ("leakage", "warnings") for w in (results.get(key) or [])}  # said in Warnings
    items += [f"<li>{html.escape(str(sel[k]))}</li>" for k in ("not_chosen", "warning")
              if sel.get(k) and str(sel[k]) not in warned]
    if not items:
        return []
    grids = "".join(f"<details><summary>{html.escape(str(c.get('method', 'descriptor')))}: every setting scored"
                    f"</summary>{table_html(*grid_rows(grid_of(c)))}</details>" for c in picks if grid_of(c))
    only = "<p>Chosen on the validation split only: no other split was read to choose.</p>" if picks else ""
    return [Section("choices", "Chosen on val", f"<ul>{''.join(items)}</ul>{grids}{only}")]


def grid_of(choice: Any) -> list[dict[str, Any]]:
    """The settings a choice scored: an HVPR choice's ``grid``, or the descriptor choice's ``scores`` as rows."""
    if isinstance(choice.get("grid"), list):
        return [g for g in choice["grid"] if isinstance(g, dict)]
    scores = choice.get("scores")
    if not isinstance(scores, dict):
        return []
    return [{"descriptor": k, **v} for k, v in scores.items() if isinstance(v, dict)]


def grid_rows(grid: Sequence[Any]) -> tuple[list[str], list[list[str]]]:
    """Header and rows of a choice's grid (``[{"setting": value, ..., "recall@1": r}, ...]``)."""
    header = list(dict.fromkeys(k for g in grid for k in g))
    return header, [[f"{g[k]:.3g}" if isinstance(g.get(k), float) else str(g.get(k, "")) for k in header]
                    for g in grid]


def notes_section(results: Any) -> list[Section]:
    """A ``notes`` section when a learned method is below its model-free counterpart, R@1 is over few queries
    (the results' ``"few_queries"``), or a default K's column is trivial (``"trivial_ks"``); none otherwise."""
    texts = [n.text() for n in learned_below_baseline(results)]
    texts += [results[k] for k in ("few_queries", "trivial_ks") if isinstance(results.get(k), str)]
    if not texts:
        return []
    items = "".join(f"<li>{html.escape(t)}</li>" for t in texts)
    return [Section("notes", "Notes", f"<ul>{items}</ul>")]


def warnings_section(results: Any) -> list[Section]:
    """A ``warnings`` section with what the evaluation warned of (the results' ``"leakage"``: queries a model was
    trained on or chose its epoch on, then ``"warnings"``: the data and settings), beside the table it qualifies
    (the report is what gets shared; stderr is not); none when nothing was said."""
    lines = [str(w) for key in ("leakage", "warnings") for w in (results.get(key) or []) if w]
    if not lines:
        return []
    items = "".join(f"<li>{html.escape(line)}</li>" for line in dict.fromkeys(lines))
    return [Section("warnings", "Warnings", f"<p>The evaluation said these beside its numbers:</p><ul>{items}</ul>")]


def radii_section(results: Any) -> list[Section]:
    """A ``radii`` section with ``--extra-radius``: per method and radius, Recall@K within that radius (the
    entries' ``radii``; none without extra radii)."""
    cfg = results.get("config") or {}
    radii = [float(r) for r in cfg.get("extra_radii") or ()]
    if not radii:
        return []
    ks = [int(k) for k in cfg.get("ks") or (1, 5, 10, 20)]
    rows = []
    for name, entry in (results.get("methods") or {}).items():
        within = (entry.get("radii") or {}) if isinstance(entry, dict) else {}
        for r in radii:
            at = within.get(str(r)) or within.get(f"{r:g}") or {}
            rows.append([name, f"{r:g}", *(f"{at[f'recall@{k}']:.3f}" if isinstance(at.get(f"recall@{k}"), float)
                                           else "–" for k in ks)])
    explicit = cfg.get("ground_truth") == "explicit positives"
    radius = cfg.get("radius")
    intro = ("<p>Recall@K counting a retrieved reference within each radius of one of the query's positives "
             "(--extra-radius; the reference traverse's positions), beside the results' explicit positives.</p>"
             if explicit else "<p>Recall@K at other localisation radii (--extra-radius) than the results' "
             f"{f'{radius:g}' if isinstance(radius, (int, float)) else html.escape(str(radius))}.</p>")
    table = table_html(["method", "radius", *(f"R@{k}" for k in ks)], rows, sortable=True)
    return [Section("radii", "Other radii", f'{intro}<div class="wide">{table}</div>')]


def calibration_section(results: Any) -> list[Section]:
    """A ``calibrated`` section with ``--target-precision``: per method, the threshold calibrated on the
    calibration split (or why none), what it accepts of the evaluated queries and the precision achieved with its
    interval, a missed target said in its row and below the table (none without calibration)."""
    cfg = results.get("config") or {}
    target = cfg.get("target_precision")
    if target is None:
        return []
    header = ["method", "threshold", "accepted", "precision", "interval", "recall", "target met"]
    rows, missed, declined = [], [], []
    for name, entry in (results.get("methods") or {}).items():
        c = entry.get("calibrated") if isinstance(entry, dict) else None
        if not isinstance(c, dict):
            continue
        cal = c.get("calibration") or {}
        if cal.get("threshold") is None:
            rows.append([name, "–", "none (abstains)", "–", "–", "–", "declined"])
            declined.append(f"<li>{html.escape(name)}: {html.escape(str(cal.get('reason', '')))}</li>")
            continue
        met = {True: "yes", False: "NO", None: "–"}[c.get("target_met")]
        missed += [name] if c.get("target_met") is False else []
        rows.append([name, f"{cal['threshold']:.4g}", f"{c['accepted']} of {c['queries']}",
                     "–" if c.get("precision") is None else f"{c['precision']:.3f}",
                     _interval(c.get("precision_interval")), f"{c.get('recall', 0.0):.3f}", met])
    kind = " (sequence confidence)" if cfg.get("confidence") == "sequence" else ""
    intro = (f"<p>Confidence thresholds{kind} calibrated on {html.escape(str(cfg.get('calibrate_split')))} for a "
             f"precision of at least {target:g} (risk {cfg.get('risk')}), applied to the evaluated queries.</p>")
    why_missed = ("The calibration split holds queries the models were trained on (see the warnings), where they "
                  "are right more often than on new queries, so its threshold promises too much: calibrate on "
                  "queries apart from training." if cfg.get("calibrated_on_training_queries") is True else
                  "The promise is for queries drawn like the calibration split's; a gap beyond the interval means "
                  "the evaluated queries differ from them (e.g. a harder stretch of the route).")
    warn = (f"<p><b>Below the target: {html.escape(', '.join(missed))}.</b> {why_missed}</p>") if missed else ""
    why = f"<p>Declined (no threshold keeps the promise on the calibration split):</p><ul>{''.join(declined)}</ul>" \
        if declined else ""
    return [Section("calibrated", "Calibrated confidence",
                    intro + table_html(header, rows, sortable=True) + why + warn)]


def _interval(bounds: Any) -> str:
    """``[lo, hi]`` of a precision interval at 3 decimals, as the CLI prints it (``–`` when unknown)."""
    try:
        lo, hi = (float(b) for b in bounds)
    except (TypeError, ValueError):
        return "–"
    return f"[{lo:.3f},\u00a0{hi:.3f}]"  # a non-breaking space: the interval never wraps
