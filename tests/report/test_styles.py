"""Figures that read at 25 methods: families, distinct styles, a legend beside the axes; a sortable table."""

from __future__ import annotations

import numpy as np

from seqnet.methods.grammar import valid_methods
from seqnet.report.styles import FAMILIES, grouped, method_family, method_styles
from seqnet.report.tables import pr_figure, recall_figure

MANY = ["single", "s1", "smoothing", "delta", "delta-paper", "seqnet", "raw+seqmatch", "s1+seqmatch",
        "delta+seqmatch", "seqnet+seqmatch", "raw+seqmatch-rev", "raw+vseqmatch", "s1+vseqmatch", "delta+vseqmatch",
        "raw+graph", "s1+graph", "raw+grh", "s1+grh", "hvpr", "hvpr-fused", "hvpr-single", "hvpr-s1", "hvpr-delta",
        "hvpr-seqnet", "hvpr-smoothing"]


def test_families():
    assert method_family("single") == method_family("s1") == "k-NN, single image"
    assert method_family("seqnet") == method_family("delta") == "k-NN, sequence descriptor"
    assert method_family("raw+seqmatch") == method_family("s1+seqmatch-rev") == "SeqMatch"
    assert method_family("hvpr-fused:s1+graph") == method_family("hvpr") == "HVPR"
    assert method_family("given distances") == "other"
    assert all(method_family(m) in FAMILIES for m in valid_methods())
    order = [f for f, _ in grouped(["hvpr", "single", "raw+graph", "s1"])]
    assert order == ["k-NN, single image", "graph", "HVPR"]


def test_no_two_methods_look_alike():
    for names in (MANY, valid_methods()):
        styles = method_styles(names)
        looks = {(tuple(np.round(s["color"], 3)), s["linestyle"], s["marker"]) for s in styles.values()}
        assert len(looks) == len(names)
        for _, members in grouped(names):  # within a family the colour alone tells the members apart
            assert len({tuple(np.round(styles[m]["color"], 3)) for m in members}) == len(members)


def _legend_outside(fig):
    fig.canvas.draw()
    ax = fig.axes[0]
    leg, box = ax.get_legend().get_window_extent(), ax.get_window_extent()
    return leg.x0 >= box.x1 and len(ax.get_legend().get_texts()) > len(MANY)


def test_legend_beside_the_axes_and_grouped():
    rng = np.random.default_rng(0)
    entries = {m: {"pr_curve": {"recall": sorted(rng.random(50).tolist()), "precision": rng.random(50).tolist()},
                   "auc": 0.5} for m in MANY}
    fig = pr_figure(entries, "nordland64[test]")
    assert _legend_outside(fig)
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts[0] == "k-NN, single image" and "HVPR" in texts and "hvpr-fused (AUC 0.50)" in texts
    assert fig.axes[0].get_title() == "nordland64[test]"
    assert _legend_outside(recall_figure({m: np.sort(rng.random(20)) for m in MANY}, "t"))


def test_sortable_table_and_header_less_facts():
    from seqnet.report.html import render_html
    from seqnet.report.markup import SORT_JS, Section, table_html

    t = table_html(["method", "R@1"], [["a<b", "0.5"]], sortable=True)
    assert t.startswith('<table class="sortable"><thead><tr><th>method</th>') and "a&lt;b" in t
    facts = table_html(None, [["dataset", "x"]])
    assert "<th>" not in facts and "<thead>" not in facts  # no empty heading row
    page = render_html("seqnet evaluation: nordland64[test]", [Section("results", "Results", t)])
    assert f"<script>{SORT_JS}</script>" in page and "src=" not in page


def test_the_ground_truth_has_a_hue_no_family_has():
    from seqnet.report.styles import FAMILIES, TRUTH_COLOUR

    assert all(max(abs(a - b) for a, b in zip(TRUTH_COLOUR, rgb, strict=True)) > 0.2 for rgb in FAMILIES.values())
