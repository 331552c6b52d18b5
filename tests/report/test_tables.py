"""results.md's table (:func:`seqnet.report.tables.format_markdown`): a learned method below its model-free
counterpart is marked as in the terminal table and the report, the notes listed under it; the header's ground
truth."""

from __future__ import annotations

from seqnet.report.guidance import learned_below_baseline
from seqnet.report.tables import format_markdown, ground_truth_text, mark_markdown_rows, markdown_notes


def _results(r1: dict[str, float], queries: int = 100) -> dict:
    methods = {n: {"recall@1": v, "recall@5": v, "queries": queries, "timing_ms": {"total": 1.0},
                   "method": {"seq_len": 5, "models": {}}} for n, v in r1.items()}
    return {"methods": methods, "config": {"seq_len": 5, "models": {}, "radius": 1.0}}


def _row(md: str, name: str) -> str:
    return next(line for line in md.splitlines() if line.startswith(f"| {name} |"))


def test_results_md_marks_a_learned_method_below_its_counterpart():
    res = _results({"single": 0.70, "s1": 0.50, "delta": 0.4, "seqnet": 0.6})
    md = format_markdown(res["methods"], ks=(1, 5), results=res)
    assert md.splitlines()[0].endswith("| note |")
    assert _row(md, "s1").endswith("| learned, below model-free single |")
    assert _row(md, "single").endswith("|  |") and _row(md, "seqnet").endswith("|  |")
    assert len({line.count("|") for line in md.splitlines()}) == 1  # every row has the note column
    notes = markdown_notes(learned_below_baseline(res), "test")
    assert notes.startswith("Learned methods below their model-free counterparts (test):\n\n- s1 (R@1 0.500) is "
                            "below the model-free single (0.700) on the same data; likely: ")


def test_results_md_without_a_flagged_method_is_as_before():
    res = _results({"single": 0.50, "s1": 0.70})
    md = format_markdown(res["methods"], ks=(1,), results=res)
    assert "note" not in md and md == format_markdown(res["methods"], ks=(1,))
    assert markdown_notes(learned_below_baseline(res)) == ""


def test_marks_in_the_paper_layout_rows():
    md = "| paper's row | seqnet | ours |\n|---|---|---|\n| SeqNet (S_1) | `s1` | 0.5 |\n| Single | `single` | 0.7 |"
    marked = mark_markdown_rows(md, {"s1": "learned, below model-free single (test)"})
    assert "| SeqNet (S_1) | `s1` [learned, below model-free single (test)] | 0.5 |" in marked
    assert "| Single | `single` | 0.7 |" in marked and marked.splitlines()[0] == md.splitlines()[0]
    assert mark_markdown_rows(md, {"seqnet": "x"}) == md  # the header's "seqnet" column is no row


def test_a_method_table_gets_a_note_column():
    md = "Recall@1\n\n| method | R@1 val |\n|---|---|\n| single | 0.7 |\n| s1 | 0.5 |\n\nafter"
    marked = mark_markdown_rows(md, {"s1": "learned, below model-free single (val)"}).splitlines()
    assert marked[2:6] == ["| method | R@1 val | note |", "|---|---|---|", "| single | 0.7 |  |",
                           "| s1 | 0.5 | learned, below model-free single (val) |"]
    assert marked[:2] == ["Recall@1", ""] and marked[-2:] == ["", "after"]


def test_the_header_says_the_ground_truth():
    assert ground_truth_text({"ground_truth": "radius", "radius": 1.0}) == "radius 1"
    text = ground_truth_text({"ground_truth": "explicit positives", "radius": 1.0})
    assert text.startswith("explicit positives") and "radius" not in text
