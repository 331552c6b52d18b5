"""The paper's tables as seqnet holds them (``report/paper.py``): every value against the
transcription in ``../shared/paper/seqnet_paper_results.md``, every method a valid seqnet method, and the
side-by-side layout."""

from __future__ import annotations

import re

import pytest
from conftest import SHARED_DATA

from seqnet.methods.grammar import parse_method
from seqnet.report.paper import TABLES, PaperRow, methods_of, recall_cell, recall_lookup, side_by_side

PAPER = SHARED_DATA.parent / "paper" / "seqnet_paper_results.md"


def paper_tables() -> dict[str, list[list[str]]]:
    """``{key: rows}`` of every ``## Table KEY`` section of the transcription (bold and italics dropped)."""
    if not PAPER.is_file():
        pytest.skip(f"the paper's transcription not found: {PAPER} (place ../shared beside the repo)")
    out: dict[str, list[list[str]]] = {}
    for section in re.split(r"^## ", PAPER.read_text(encoding="utf-8"), flags=re.M)[1:]:
        m = re.match(r"Table (\w+)", section)
        if not m:
            continue
        rows = [[c.strip().replace("**", "") for c in line.strip().strip("|").split("|")]
                for line in section.splitlines() if line.startswith("|") and not line.startswith("|---")]
        out[m.group(1)] = [r for r in rows[1:] if not r[0].startswith("*")]  # header and group labels dropped
    return out


def test_values_are_the_papers():
    published = paper_tables()
    assert set(published) == set(TABLES)
    for key, table in TABLES.items():
        if key == "II":  # one row of four values, no label column
            assert [list(r.values) for r in table.rows] == published[key]
            continue
        assert [[r.label, *r.values] for r in table.rows] == published[key], key


def test_every_method_is_a_seqnet_method():
    for key in ("I", "III", "S2", "S3"):
        names = methods_of(TABLES[key])
        assert names and all(parse_method(n).name == n for n in names)
    assert methods_of(TABLES["III"])[-1] == "hvpr-seqnet:s1+seqmatch-rev"  # one method per ours-column


def test_recall_cell():
    assert recall_cell({"recall@1": 0.8431, "recall@5": 0.9, "recall@20": 1.0}) == "0.843/0.900/1.000"
    assert recall_cell({"recall@1": 0.5}) == "0.500/-/-"
    assert recall_cell(None) == "–"


def test_side_by_side_layout():
    t = TABLES["III"]
    values = [{"raw+seqmatch": {"recall@1": 0.1, "recall@5": 0.2, "recall@20": 0.3}},
              {"raw+seqmatch-rev": {"recall@1": 0.4, "recall@5": 0.5, "recall@20": 0.6}}]
    md = side_by_side(t, ("vanilla", "reverse"), recall_lookup(values), denominator="all")
    lines = md.splitlines()
    assert "Table III" in lines[0] and "denominator (ours): all" in lines[0]
    assert lines[2] == ("| paper's row | seqnet | ours: vanilla | ours: reverse | paper: Vanilla SeqMatch | "
                        "paper: Reverse SeqMatch |")
    assert len(lines) == 4 + len(t.rows)
    raw = next(line for line in lines if line.startswith("| Raw + SeqMatch"))
    assert raw == ("| Raw + SeqMatch | `raw+seqmatch \\| raw+seqmatch-rev` | 0.100/0.200/0.300 | 0.400/0.500/0.600 | "
                   "0.49/0.69/0.85 | 0.67/0.78/0.90 |")
    single = next(line for line in lines if line.startswith("| Raw Single"))
    assert single.split(" | ")[1:5] == ["`single`", "–", "–", "0.47/0.70/0.85"]  # not measured; no reverse
    assert PaperRow("x", ("a",), ("m", None)).method_for(1) is None
