"""Reports: comparison tables (plain text and Markdown), Recall@K and precision–recall plots."""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.provenance import views_text
from ..security.files import atomic_path
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS
from .guidance import Note, format_notes, learned_below_baseline, row_marks


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "  n/a" if math.isnan(v) else f"{v:.3f}"
    return str(v)


def results_rows(methods: Mapping[str, Mapping[str, Any]], ks: Sequence[int],
                 pr: bool = False) -> tuple[list[str], list[list[str]]]:
    """Header and rows: method, R@K for each K, (with ``pr``: AUC and R@100P,) queries, the method's total time
    over all queries and per query (ms: descriptors of both sides included)."""
    extra = [("AUC", "auc"), ("R@100P", "recall@100p")] if pr else []
    header = [f"method (R@K ÷ {denominator_label(methods)})", *(f"R@{k}" for k in ks), *(h for h, _ in extra),
              "queries", "total ms", "ms/query"]
    rows = []
    for name, r in methods.items():
        total, n = r.get("timing_ms", {}).get("total", float("nan")), r.get("queries") or 0
        rows.append([name, *(_fmt(r.get(f"recall@{k}", float("nan"))) for k in ks),
                     *(_fmt(float(_or_nan(r.get(key)))) for _, key in extra), str(r.get("queries", "")),
                     f"{total:.1f}", f"{total / n:.2f}" if n else "-"])
    return header, rows


def _or_nan(v: Any) -> Any:
    """``v``, or NaN for a missing or null entry (a method without a PR summary)."""
    return float("nan") if v is None else v


def denominator_label(methods: Mapping[str, Mapping[str, Any]]) -> str:
    """The Recall@K denominator of results entries: ``positives`` (queries with a correct reference; also
    entries written before it was recorded) or ``all`` (every evaluated query)."""
    return "/".join(dict.fromkeys(r.get("recall_denominator", "positives") for r in methods.values())) or "positives"


def method_label(entry: Mapping[str, Any]) -> str:
    """What a results entry's method resolved to, e.g. ``seqnet(L=5) top-20 -> s1+seqmatch(L_m=5)``."""
    m = entry.get("method") or {}
    single = m.get("shortlist") in SEQUENCE_DESCRIPTORS and SEQUENCE_DESCRIPTORS[m["shortlist"]].single_frame
    short = (m["shortlist"] if single else f"{m['shortlist']}(L={m.get('seq_len')})") if m.get("shortlist") else ""
    rerank = f"{m['rerank']}(L_m={m.get('match_len')})" if m.get("rerank") else ""
    if m.get("kind") == "hvpr" and m.get("fuse_weight"):  # hvpr-fused: its score says what ran
        return f"{short} top-{m.get('top_k')} -> {rerank}/L_m + {m['fuse_weight']:g}·d({m['shortlist']})"
    if m.get("kind") == "hvpr":
        return f"{short} top-{m.get('top_k')} -> {rerank}"
    return f"k-NN {short}" if m.get("kind") == "knn" else rerank


def format_table(methods: Mapping[str, Mapping[str, Any]], ks: Sequence[int] = (1, 5, 10, 20, 100)) -> str:
    """A fixed-width text table of results (one row per method, with what it resolved to; a learned method
    below its model-free counterpart is marked: :mod:`seqnet.report.guidance`)."""
    header, rows = results_rows(methods, ks)
    header.append("what")
    marks = row_marks(learned_below_baseline({"methods": methods}))
    for row, (name, entry) in zip(rows, methods.items(), strict=True):
        row.append(method_label(entry) + (f"  [{marks[name]}]" if name in marks else ""))
    widths = [max(len(x) for x in col) for col in zip(header, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        pairs = enumerate(zip(cells, widths, strict=True))
        return "  ".join(c.ljust(w) if i in (0, len(cells) - 1) else c.rjust(w) for i, (c, w) in pairs).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])


def format_markdown(methods: Mapping[str, Mapping[str, Any]], ks: Sequence[int] = (1, 5, 20),
                    results: Mapping[str, Any] | None = None) -> str:
    """A Markdown table of results: R@K, AUC and R@100P (precision–recall), queries, per-stage timings; a learned
    method below its model-free counterpart marked in a last ``note`` column (only when one is), as the terminal
    table and the report mark it (``results``: the whole results, whose config names the causes; default just
    ``methods``)."""
    header, rows = results_rows(methods, ks, pr=True)
    stages = sorted({s for r in methods.values() for s in r.get("timing_ms", {}) if s != "total"})
    header = [*header, *(f"{s} ms" for s in stages)]
    for row, r in zip(rows, methods.values(), strict=True):
        timing = r.get("timing_ms", {})
        row.extend(f"{timing[s]:.1f}" if s in timing else "–" for s in stages)
    marks = row_marks(learned_below_baseline(results if results is not None else {"methods": methods}))
    if marks:
        header.append("note")
        for row, name in zip(rows, methods, strict=True):
            row.append(marks.get(name, ""))
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out) + "\n"


def markdown_notes(notes: Sequence[Note], label: str = "") -> str:
    """The notes on learned methods below their model-free counterparts as a Markdown list to print under a
    results table (the same lines as the terminal's, :func:`seqnet.report.guidance.format_notes`; ``label``: which
    evaluation they are about); empty without notes."""
    lines = format_notes(list(notes))
    if not lines:
        return ""
    about = f" ({label})" if label else ""
    return "\n".join([f"Learned methods below their model-free counterparts{about}:", "",
                      *(f"- {line.removeprefix('note: ')}" for line in lines)]) + "\n"


def mark_markdown_rows(md: str, marks: Mapping[str, str]) -> str:
    """``md`` with the rows of flagged methods marked in each Markdown table: a table whose first column names
    methods gets a last ``note`` column (the mark, or nothing); in another, a cell naming a flagged method in
    backticks (as :func:`seqnet.report.paper.side_by_side` writes its seqnet column) gets ``[mark]``."""
    lines = md.split("\n")
    i = 0
    while i < len(lines):
        if _is_row(lines[i]) and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            end = i + 2
            while end < len(lines) and _is_row(lines[end]):
                end += 1
            lines[i:end] = _marked_table(lines[i:end], marks)
            i = end
        else:
            i += 1
    return "\n".join(lines)


def _is_row(line: str) -> bool:
    return line.startswith("| ") and line.endswith(" |")


def _marked_table(table: list[str], marks: Mapping[str, str]) -> list[str]:
    """One Markdown table (header, ``|---|`` line, rows) with its flagged rows marked (:func:`mark_markdown_rows`)."""
    rows = [line[2:-2].split(" | ") for line in table[2:]]
    if any(r[0].strip() in marks for r in rows):
        return [table[0] + " note |", table[1] + "---|",
                *(line + f" {marks.get(r[0].strip(), '')} |" for line, r in zip(table[2:], rows, strict=True))]
    out = table[:2]
    for cells in rows:
        for k, cell in enumerate(cells):
            name = cell.strip()
            if len(name) > 2 and name[0] == name[-1] == "`" and name[1:-1] in marks:
                cells[k] = f"{cell} [{marks[name[1:-1]]}]"
                break
        out.append("| " + " | ".join(cells) + " |")
    return out


def ground_truth_text(config: Mapping[str, Any]) -> str:
    """What counted as correct, as the header of a results table says it (from an evaluation's config): the
    dataset's explicit positives, or the radius."""
    if config.get("ground_truth") == "explicit positives":
        return "explicit positives (a hit is one of the query's positives)"
    return f"radius {float(config.get('radius', float('nan'))):g}"


def descriptors_text(record: Mapping[str, Any] | None) -> str | None:
    """The descriptors an evaluation compared (its results' ``descriptors``, see
    :func:`seqnet.eval.evaluation.descriptor_record`) in one line: method, views, image size, PCA, D and provenance
    id; one part per side when the sides differ; None when not recorded."""
    if not isinstance(record, Mapping) or not record:
        return None
    sides = {side: _side_text(r) for side, r in record.items() if isinstance(r, Mapping)}
    if len(set(sides.values())) == 1:
        return next(iter(sides.values()))
    return "; ".join(f"{side}: {text}" for side, text in sides.items())


def _side_text(r: Mapping[str, Any]) -> str:
    what = [str(r.get("method") or r.get("kind") or "unknown method")]
    if views := views_text(r.get("views")):
        what.append(views)
    if r.get("size") not in (None, "native"):
        what.append(f"size {r['size']}")
    if r.get("pca"):
        what.append(f"PCA to {r['pca']}")
    prov = f"provenance {r['provenance']}" if r.get("provenance") else "provenance unknown"
    return f"{', '.join(what)}, D={r.get('dim')} ({prov})"


def plot_recall_curves(curves: Mapping[str, np.ndarray], path: str | Path, title: str = "") -> Path:
    """Save Recall@K curves (K = 1..len) as a PNG, one line per method (paper Fig. 3 style)."""
    return save_figure(recall_figure(curves, title), path)


def method_colours(n: int) -> list[Any]:
    """``n`` distinct colours (tab20: the 10 dark shades first, then the light ones), cycling after 20."""
    import matplotlib

    tab20 = matplotlib.colormaps["tab20"].colors
    colours = [*tab20[::2], *tab20[1::2]]
    return [colours[i % 20] for i in range(n)]


def recall_figure(curves: Mapping[str, np.ndarray], title: str = "") -> Any:
    """A figure of Recall@K curves (K = 1..len), one line per method, styled by family
    (:func:`seqnet.report.styles.method_styles`), the legend beside the axes grouped by family."""
    from matplotlib.ticker import MaxNLocator

    from .styles import family_legend, method_styles

    styles = method_styles(list(curves))
    fig, ax = new_figure(*figure_size(len(curves)))
    for name, c in curves.items():
        ax.plot(np.arange(1, len(c) + 1), c, markersize=4, label=name, linewidth=1.3, **styles[name])
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("K (number of top reference candidates)")
    ax.set_ylabel("Recall@K")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    family_legend(ax, list(curves))
    if title:
        ax.set_title(title, parse_math=False)  # a dataset's name is text, never mathtext (``$\\foo$`` fails)
    return fig


def figure_size(n_methods: int) -> tuple[float, float]:
    """``(width, height)`` in inches of a figure of ``n_methods`` curves with their legend beside it: taller as
    the legend grows (about 0.16 inch a row, family headings included), wider for its second column."""
    rows = n_methods + 9  # at most one heading per family
    height = max(4.5, min(0.16 * rows, 7.5))
    return (9.5 if rows > 30 else 7.5), height


def plot_pr_curves(methods: Mapping[str, Mapping[str, Any]], path: str | Path, title: str = "") -> Path:
    """Save :func:`pr_figure` of results entries as a PNG."""
    return save_figure(pr_figure(methods, title), path)


def pr_figure(methods: Mapping[str, Mapping[str, Any]], title: str = "") -> Any:
    """The precision–recall curves of results entries (``pr_curve``: ``{"precision", "recall"}``, and
    ``auc`` for the legend), one line per method styled by family (a marker every tenth of the curve); entries
    without a curve are left out."""
    from .styles import family_legend, method_styles

    entries = [(n, r) for n, r in methods.items() if (r.get("pr_curve") or {}).get("recall")]
    styles = method_styles([n for n, _ in entries])
    fig, ax = new_figure(*figure_size(len(entries)))
    for name, r in entries:
        c = r["pr_curve"]
        ax.plot(c["recall"], c["precision"], label=name, linewidth=1.3, markersize=4,
                markevery=max(1, len(c["recall"]) // 10), **styles[name])
    ax.set_xlabel("recall (top-1 correct, accepted by confidence)")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    family_legend(ax, [n for n, _ in entries],
                  {n: f"{n} (AUC {float(r.get('auc') or 0.0):.2f})" for n, r in entries})
    if title:
        ax.set_title(title, parse_math=False)  # a dataset's name is text, never mathtext (``$\\foo$`` fails)
    return fig


def new_figure(width: float, height: float, ncols: int = 1) -> tuple[Any, Any]:
    """A matplotlib ``Figure`` with ``ncols`` axes drawn by the Agg canvas (no pyplot, no global backend)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, ncols)
    return fig, axes


def save_figure(fig: Any, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` as a PNG atomically."""
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
    return path


def figure_png(fig: Any, dpi: int = 100) -> bytes:
    """``fig`` as PNG bytes (for embedding in a report)."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()
