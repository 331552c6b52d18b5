"""A self-contained HTML report of an evaluation: one file, inline CSS, every figure a PNG embedded
as a base64 ``data:`` URI, no script and no external URL, so it opens offline, in a mail or an
archive, exactly as written.

Sections (their ``id``): ``summary`` (what was evaluated and the resolved configuration),
``results`` (Recall@K, precision–recall AUC, R@100P, queries, time per method), ``choices`` (what was
chosen on val and why, when something was), ``notes`` (only when a
learned method is below its model-free counterpart: :mod:`seqnet.report.guidance`), ``radii`` (with
``--extra-radius``: Recall@K within each radius), ``calibrated`` (with ``--target-precision``), ``recall``
(Recall@K curves), ``pr`` (precision–recall curves), ``matrix`` (the single-image descriptor
distance matrix of the evaluated items, downsampled, with the ground truth and each method's top-1
over it), ``gallery`` (example queries — the query window frames above the top-1 reference window
frames, marked correct or wrong, failures first — when the dataset has image names and the image
folders or videos are given), and with positions in metres ``trajectory`` (each query placed where it was
recognised on the reference route) and ``pairs`` (query | matched | true reference frame of the worst and best
queries, with the frames). Experiments add their own sections before these (:func:`write_html_report`). An
evaluation against a map (``seqnet eval --index``) has no dataset: its ``matrix`` and ``gallery`` say why they
are empty.
"""

from __future__ import annotations

import dataclasses
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from ..core.config import Config, check_int
from ..core.log import logger
from ..data.traverse import Dataset
from ..methods.grammar import parse_method
from ..metrics.consistency import CONFIDENCES
from ..metrics.recall import recall_curve
from ..security.files import write_text_atomic
from .figures import GalleryItem, gallery_png, matrix_figure, pick_examples, window_names
from .guidance import learned_below_baseline, row_marks
from .markup import SORT_JS, Section, png_tag, table_html
from .notes import calibration_section, choices_section, notes_section, radii_section, truth_fact, warnings_section
from .sources import inside_name, swapped_sources
from .styles import method_family
from .tables import descriptors_text, figure_png, pr_figure, recall_figure, results_rows

SECTIONS = ("summary", "results", "recall", "pr", "matrix", "gallery")  # always; "trajectory", "pairs" with positions
CSS = """body{font-family:sans-serif;margin:2em auto;padding:0 1em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:2px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}nav a{margin-right:1em}pre{background:#f4f4f4;padding:.5em;
overflow-x:auto;font-size:80%}.ex{display:inline-block;margin:4px;padding:4px;border:3px solid}
.ok{border-color:#2a2}.bad{border-color:#c22}.ex img{image-rendering:pixelated;width:100%}
.ex p{margin:2px;font-size:80%}img{max-width:100%}table.sortable th{cursor:pointer;user-select:none}
table.sortable td:nth-child(2),table.sortable th:nth-child(2){text-align:left;white-space:nowrap}
table.facts td{text-align:left}table.sortable{font-size:90%}.wide{overflow-x:auto;max-width:100%}
#results td,#results th{padding:2px 5px}#results td:nth-child(2){white-space:normal;min-width:7em}
#results td:last-child,#results th:last-child{text-align:left;white-space:normal;min-width:9em;max-width:14em}
th.asc:after{content:" \\25B2"}th.desc:after{content:" \\25BC"}"""


@dataclasses.dataclass(frozen=True)
class ReportConfig(Config):
    """Settings of the HTML report.

    Attributes:
        title: the page title (None: "seqnet evaluation: " and the evaluated dataset's name).
        k_max: Recall@K curves for K = 1..k_max.
        matrix_side: the distance matrix is drawn at most this many rows and columns.
        gallery_method: the method of the gallery (None: the one with the best R@1).
        gallery_size: example queries shown (failures first).
        query_images, ref_images: folders of the query / reference images (named as in the
            dataset); without both, no gallery.
    """

    title: str | None = None
    k_max: int = 20
    matrix_side: int = 300
    gallery_method: str | None = None
    gallery_size: int = 12
    query_images: str | None = None
    ref_images: str | None = None

    def __post_init__(self) -> None:
        for key in ("k_max", "matrix_side", "gallery_size"):
            self._set(key, check_int(key, getattr(self, key), 1))
        if self.gallery_method is not None:
            self._set("gallery_method", parse_method(self.gallery_method).name)
        for key in ("query_images", "ref_images"):
            if getattr(self, key) is not None:
                self._set(key, str(getattr(self, key)))


def summary_section(ev: Any, conf: ReportConfig, ds: Dataset | None = None) -> Section:
    """What was evaluated, on what (the ground truth in ``ds``'s unit), and the resolved configuration."""
    cfg = ev.results["config"]
    first = next(iter(ev.results["methods"].values()))
    truth = truth_fact(cfg, ds)
    counts = sorted({r.get("queries") for r in ev.results["methods"].values() if isinstance(r.get("queries"), int)})
    queries = (f"{counts[0]}–{counts[-1]} (by method: the results table's column)" if len(counts) > 1 else
               first.get("queries", ""))
    facts = [("dataset", cfg.get("dataset", "")), ("queries evaluated", queries),
             ("reference items (frames with a full window)", len(ev.r_items)), truth, ("L", cfg.get("seq_len", "")),
             ("L_m", cfg.get("match_len") or cfg.get("seq_len", "")), ("window", cfg.get("window", "")),
             ("methods", ", ".join(ev.results["methods"])), ("seqnet", __version__)]
    if (described := descriptors_text(ev.results.get("descriptors"))) is not None:
        facts.insert(4, ("descriptors", described))
    if cfg.get("index"):  # seqnet eval --index: the reference side is the map's
        facts.insert(1, ("reference", f"the map {cfg['index']}"))
    config = html.escape(json.dumps(cfg, indent=1, default=str))
    return Section("summary", "Summary", table_html(None, facts)
                   + f"<details><summary>resolved configuration</summary><pre>{config}</pre></details>")


COLUMNS_NOTE = ("R@K: the share of queries with a correct reference that have one among the top K retrieved. PR AUC: "
                "the area under the precision–recall curve of the top-1 answers thresholded by their confidence "
                "(average precision). R@100P: the largest share of those queries that a confidence threshold "
                "accepts while every accepted answer is correct (recall at 100 % precision). Click a column's "
                "heading to sort by it (again: the other way).")


def results_section(ev: Any) -> Section:
    """The results table: Recall@K, AUC, R@100P, queries, time."""
    ks = ev.results["config"].get("ks", [1, 5, 10, 20])
    header, rows = results_rows(ev.results["methods"], ks)
    marks = row_marks(learned_below_baseline(ev.results))  # learned below its model-free counterpart
    for row, (name, r) in zip(rows, ev.results["methods"].items(), strict=True):
        row.extend(f"{r[k]:.3f}" if isinstance(r.get(k), float) else "" for k in ("auc", "recall@100p"))
        row.insert(1, method_family(name))
        row.append(marks.get(name, ""))
    table = table_html([header[0], "family", *header[1:], "PR AUC", "R@100P", "note"], rows, sortable=True)
    return Section("results", "Results", f'<div class="wide">{table}</div>' + f"<p>{COLUMNS_NOTE}</p>")


def gallery_section(ev: Any, ds: Dataset, conf: ReportConfig) -> Section:
    """Example queries beside their top-1 reference window, failures first (or why there are none)."""
    if not (conf.query_images and conf.ref_images and ds.query.names and ds.reference.names):
        why = "the dataset has no image names" if not (ds.query.names and ds.reference.names) else \
            "no image folders were given (seqnet eval --report --images-query DIR --images-ref DIR)"
        return Section("gallery", "Example queries", f"<p>No gallery: {html.escape(why)}.</p>")
    methods = ev.results["methods"]
    name = conf.gallery_method or max(methods, key=lambda m: methods[m].get("recall@1", -1.0))
    entry, ranked = methods[name]["method"], ev.retrieved[name]
    m = parse_method(name)
    single = m.single_frame
    length, mode = 1 if single else entry.get("match_len") or entry["seq_len"], ev.results["config"]["window"]
    view = ev.view(name)  # the method's own items (a single-frame method: every frame)
    correct = view.truth.hits(ranked[:, :1])[:, 0]
    cells = []
    for row in pick_examples(correct, view.truth.has_positive(), conf.gallery_size):
        top = int(ranked[row, 0])
        item = GalleryItem(row, window_names(ds.query, int(view.q_items[row]), length, mode),
                           window_names(ds.reference, int(view.r_items[top]), length, mode) if top >= 0 else [],
                           bool(correct[row]), float(ev.confidence[name][row]))
        notes: list[str] = []
        png = gallery_png(item, Path(conf.query_images), Path(conf.ref_images), notes=notes) \
            if item.ref_frames else None
        cells.append(gallery_cell(item, png, notes[0] if notes else "", (conf.query_images, conf.ref_images)))
    head = (f"<p>Method <b>{html.escape(name)}</b>: each example shows the query window (top row) above the "
            f"top-1 reference window (bottom row), {length} frame(s); green: correct, red: wrong.</p>")
    return Section("gallery", "Example queries", head + "".join(cells))


def gallery_cell(item: GalleryItem, png: bytes | None, note: str = "",
                 folders: tuple[str | None, str | None] = (None, None)) -> str:
    """One example of the gallery (``note``: why its pictures are left out), its images named within the query's
    and the reference's image ``folders`` where they lie inside them."""
    status = "correct" if item.correct else "wrong"
    query, ref = item.query_frames[len(item.query_frames) // 2], \
        item.ref_frames[len(item.ref_frames) // 2] if item.ref_frames else None
    text = (f"<p>{status}: query {html.escape(inside_name(query, folders[0]))} → "
            f"{html.escape(inside_name(ref, folders[1])) if ref is not None else 'none'}"
            f" (confidence {item.confidence:.2f})</p>")
    why = f": {note[:500]}" if note else ""
    image = png_tag(png, f"query {item.query}") if png is not None else \
        f"<p>(pictures left out{html.escape(why)})</p>"
    return f'<div class="ex {"ok" if item.correct else "bad"}" style="width:300px">{image}{text}</div>'


CONFIDENCE_NOTES = {
    "ratio": "Confidence of a top-1: the ratio test against the best other place (seqnet.metrics.precision_recall).",
    "sequence": "Confidence of a top-1: how many of the L queries on either side have a top-1 in line with it, "
                "ties broken by the ratio test against the best other place (seqnet.metrics.consistency).",
}


def evaluation_sections(ev: Any, ds: Dataset | None, conf: ReportConfig) -> list[Section]:
    """The report sections of one :class:`~seqnet.eval.evaluate.Evaluation` of the dataset ``ds`` (the
    evaluated split: its traverses give the descriptors and image names; None: an evaluation against a map, whose
    sections that read the dataset say why they are empty)."""
    curves = {m: recall_curve(r, ev.view(m).truth, conf.k_max) for m, r in ev.retrieved.items()}
    kind = ev.results.get("config", {}).get("confidence")
    kind = kind if kind in CONFIDENCES else "ratio"
    pr = pr_figure(ev.results["methods"], f"precision–recall ({kind} confidence)")
    return [
        summary_section(ev, conf, ds),
        results_section(ev),
        *warnings_section(ev.results),
        *choices_section(ev.results),
        *notes_section(ev.results),
        *radii_section(ev.results),
        *calibration_section(ev.results),
        Section("recall", "Recall@K", png_tag(figure_png(recall_figure(curves, "Recall@K")), "Recall@K curves")),
        Section("pr", "Precision–recall", png_tag(figure_png(pr),
                                                   "precision-recall curves")
                + f"<p>{CONFIDENCE_NOTES[kind]}</p>"),
        *(dataset_sections(ev, ds, conf) if ds is not None else without_dataset()),
    ]


MAP_ONLY = ("the queries were evaluated against a prebuilt map (seqnet eval --index), and this section reads both "
            "sides' frames and names from a dataset; evaluate the dataset without --index to see it")


def without_dataset() -> list[Section]:
    """The sections of an evaluation against a map that need the reference side as a dataset: a line saying why
    they are empty."""
    return [Section("matrix", "Distance matrix", f"<p>No distance matrix: {html.escape(MAP_ONLY)}.</p>"),
            Section("gallery", "Example queries", f"<p>No gallery: {html.escape(MAP_ONLY)}.</p>")]


def dataset_sections(ev: Any, ds: Dataset, conf: ReportConfig) -> list[Section]:
    """The sections that read the evaluated dataset ``ds``: the distance matrix, the gallery, the places."""
    return [
        Section("matrix", "Distance matrix", png_tag(figure_png(matrix_figure(ev, ds.query, ds.reference,
                                                                              conf.matrix_side)), "distance matrix")
                + f"<p>{matrix_note(ev)}</p>"),
        gallery_section(ev, ds, conf),
        *place_sections(ev, ds, conf),
    ]


def place_sections(ev: Any, ds: Dataset, conf: ReportConfig) -> list[Section]:
    """With positions in metres: the trajectory plot; with the frames too (image folders or videos): the pair
    images of the worst and best queries (:mod:`seqnet.report.places`)."""
    from .places import has_route, pair_items, trajectory_png

    if not (has_route(ds) and len(ev.retrieved)):
        return []
    png, name = trajectory_png(ev, ds)
    out = [Section("trajectory", "Trajectory", png_tag(png, "trajectory") + f"<p>Method <b>{html.escape(name)}</b>: "
                   "each evaluated query placed where it was recognised on the reference route (green: within the "
                   "radius, red: wrong, a line to its true position); right: the error in metres.</p>")]
    if conf.query_images and conf.ref_images and ds.query.names and ds.reference.names:
        name, items = pair_items(ev, ds, Path(conf.query_images), Path(conf.ref_images))
        cells = "".join(f'<div class="ex {"ok" if ok else "bad"}" style="width:320px">'
                        f'{png_tag(png, "pair") if png else ""}<p>{html.escape(text)}</p></div>'
                        for ok, png, text in items)
        out.append(Section("pairs", "Worst and best queries", f"<p>Method <b>{html.escape(name)}</b>: each picture "
                           "is the query frame | the matched reference frame | the reference frame nearest to the "
                           f"query's true position.</p>{cells}"))
    return out


def matrix_note(ev: Any) -> str:
    """What the distance matrix section shows: the given distances (``eval --distances``) or the descriptors'."""
    if getattr(ev, "matrix", None) is not None:
        return "The given distances between the evaluated query and reference frames (seqnet eval --distances)."
    return "Single-image descriptor distances between the evaluated query and reference frames."


def render_html(title: str, sections: Sequence[Section]) -> str:
    """The whole page: title, a navigation bar and the sections."""
    nav = "".join(f'<a href="#{html.escape(s.id)}">{html.escape(s.title)}</a>' for s in sections)
    body = "".join(f'<section id="{html.escape(s.id)}"><h2>{html.escape(s.title)}</h2>{s.body}</section>'
                   for s in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f"<style>{CSS}</style></head><body><h1>{html.escape(title)}</h1><nav>{nav}</nav>{body}"
            f"<script>{SORT_JS}</script></body></html>\n")


def write_html_report(ev: Any, ds: Dataset | None, path: str | Path, conf: ReportConfig | None = None,
                      extra: Sequence[Section] = ()) -> Path:
    """Write the report of the evaluation ``ev`` of ``ds`` (the evaluated split; None: an evaluation against a
    map) to ``path``, with the sections ``extra`` first (e.g. an experiment's own tables and figures); returns
    ``path``."""
    conf = conf or ReportConfig()
    name = ds.name if ds is not None else ev.results.get("config", {}).get("dataset", "")
    title = conf.title or f"seqnet evaluation: {name}"
    swapped = swapped_sources(ds.extra, conf.query_images, conf.ref_images) if ds is not None else None
    if swapped:
        logger.warning("%s", swapped)
        extra = [Section("sources", "Picture sources", f"<p><b>Warning:</b> {html.escape(swapped)}.</p>"), *extra]
    return write_text_atomic(Path(path), render_html(title, [*extra, *evaluation_sections(ev, ds, conf)]))


def figure_section(id_: str, title: str, fig: Any, text: str = "") -> Section:
    """A section holding one matplotlib figure (embedded) and an optional paragraph of text."""
    return Section(id_, title, png_tag(figure_png(fig), title) + (f"<p>{html.escape(text)}</p>" if text else ""))


def rows_as_text(rows: Sequence[Sequence[Any]]) -> list[list[str]]:
    """Table cells as text (floats with 3 decimals, None as a dash)."""
    return [["–" if c is None else f"{c:.3f}" if isinstance(c, (float, np.floating)) else str(c) for c in r]
            for r in rows]
