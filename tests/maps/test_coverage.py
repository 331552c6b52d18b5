"""A map of one split's reference range says so at build, and localize says when the query is far longer (hunt 5 F3:
the test split's 60 of 300 frames mapped by default, the whole route answered among them without a word)."""

from __future__ import annotations

import json

from seqnet.cli import main as cli
from seqnet.maps.coverage import coverage_line, partial_map_note


def meta(split, a, b, total):
    return {"source": {"dataset": "ds", "split": split, "reference_range": [a, b], "dataset_reference_frames": total}}


def test_the_lines_name_the_range_of_how_many_and_the_flag():
    part = coverage_line(meta("test", 240, 300, 300), split_given=False)
    assert "the test split's frames 240:300, 60 of the 300 of dataset ds" in part and "--split all" in part
    assert "no --split: the test split, the default" in part
    assert coverage_line(meta("test", 0, 300, 300)) == "reference: all 300 frames of dataset ds, the test split's"
    assert coverage_line(meta("all", 0, 300, 300), split_given=False) == "reference: all 300 frames of dataset ds"
    old = {"source": {"dataset": "ds", "split": "test", "reference_range": [240, 300]}}  # built before the count
    assert "60 of dataset ds" in coverage_line(old) and partial_map_note(old, "m", 300) is None
    note = partial_map_note(meta("test", 240, 300, 300), "m", 300)
    assert "300 frames, 5.0 times the map's 60" in note and "reference frames 240:300 of the 300" in note
    assert "seqnet index build --split all" in note
    assert partial_map_note(meta("test", 240, 300, 300), "m", 120) is None  # at most twice the map: the split's
    assert partial_map_note(meta("all", 0, 300, 300), "m", 3000) is None  # the whole route: a long query is fine
    assert coverage_line(None) is None and partial_map_note({}, "m", 10) is None


def test_build_and_localize_say_the_map_holds_part_of_the_route(synth_dir, tmp_path, capsys):
    mp, out = tmp_path / "map", tmp_path / "t.csv"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "single", "--rerank",
                "raw+seqmatch", "--seq-len", "4", "--window", "causal", "--out", str(mp)]) == 0
    said = capsys.readouterr().out
    assert "reference: the test split's frames 151:193, 42 of the 193 of dataset" in said, said
    assert "(no --split: the test split, the default)" in said and "--split all" in said
    query = synth_dir / "query" / "descriptors.npy"  # the whole route: 197 frames against 42
    assert cli(["localize", "--map", str(mp), "--query", str(query), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "the query has 197 frames, 4.7 times the map's 42" in err, err
    warnings = json.loads(out.with_suffix(".json").read_text())["warnings"]
    assert any("seqnet index build --split all" in w for w in warnings), warnings
