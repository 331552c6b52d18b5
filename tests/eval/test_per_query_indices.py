"""--per-query CSV / JSONL: indices are rows of the dataset's whole query / reference lists, with their names."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.data.io import load_dataset


@pytest.mark.parametrize("route", ["descriptors", "distances", "index"])
def test_reference_indices_are_the_datasets_rows_on_a_split(synth_dir, tmp_path, route):
    """Hunt F5: on a split whose reference range starts at 450, reference 120 meant row 570 of reference/names.txt;
    the file now gives the dataset's rows and the names, and a row's `correct` agrees with the named positions."""
    whole = load_dataset(synth_dir)
    assert whole.ranges("test")["reference"][0] > 0
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--split", "test", "--device", "cpu"]
    if route == "distances":
        q, r = whole.query.descriptors, whole.reference.descriptors
        np.save(tmp_path / "d.npy", np.sqrt(((q[:, None, :] - r[None]) ** 2).sum(-1)))
        argv += ["--distances", str(tmp_path / "d.npy")]
    if route == "index":
        assert main(["-q", "index", "build", "--dataset", str(synth_dir), "--split", "test", "--shortlist", "delta",
                     "--rerank", "raw+seqmatch", "--seq-len", "4", "--out", str(tmp_path / "map"),
                     "--device", "cpu"]) == 0
        argv = [*argv[:5], "delta", *argv[6:], "--index", str(tmp_path / "map")]
    assert main([*argv, "--per-query", str(tmp_path / "pq.jsonl")]) == 0
    rows = [json.loads(line) for line in (tmp_path / "pq.jsonl").read_text().splitlines()]
    (a, b), (c, d) = whole.ranges("test")["query"], whole.ranges("test")["reference"]
    assert rows and all(a <= r["query_index"] < b for r in rows)
    right = 0
    for r in rows:
        assert r["query_name"] == whole.query.names[r["query_index"]]
        refs = [j for j in r["reference_indices"] if j >= 0]
        assert refs and all(c <= j < d for j in refs)
        assert r["reference_names"][: len(refs)] == [whole.reference.names[j] for j in refs]
        near = [bool(np.linalg.norm(whole.reference.positions[j] - whole.query.positions[r["query_index"]])
                     <= whole.radius) for j in refs]
        right += near == r["correct"][: len(refs)]
    assert right == len(rows) or whole.positives is not None
    if route == "descriptors":  # the CSV: renamed columns, so a reader of the split-relative ones fails loudly
        assert main([*argv, "--per-query", str(tmp_path / "pq.csv")]) == 0
        first = next(csv.DictReader((tmp_path / "pq.csv").open()))
        assert "references" not in first and "query_frame" not in first
        assert first["reference_names"].split(";")[0] == whole.reference.names[int(first["reference_indices"]
                                                                                   .split(";")[0])]


def test_a_per_query_csv_of_the_old_columns_is_still_seqnets_to_replace(synth_dir, tmp_path):
    """A file seqnet wrote before the columns were renamed is replaced without --overwrite, as before."""
    pq = tmp_path / "pq.csv"
    pq.write_text("method,query_frame,query_name,references,scores,correct,has_positive,confidence\n")
    assert main(["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--device", "cpu",
                 "--per-query", str(pq)]) == 0
    assert pq.read_text().startswith("method,query_index,query_name,reference_indices,reference_names,")
