"""A query a sequence method cannot answer as given is said (:mod:`seqnet.localize.order`): frames not in capture
order (the estimates jump around the map), and fewer frames than the method's window (no estimate at all)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from seqnet.core.provenance import sidecar
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.stream import Query, stream


def query_file(synth_dataset, tmp_path, rows: np.ndarray):
    """``rows`` of the synthetic query traverse as a descriptor file carrying its provenance."""
    p = tmp_path / "q.npy"
    np.save(p, synth_dataset.query.descriptors[rows])
    sidecar(p).write_text(json.dumps(synth_dataset.query.provenance))
    return p


def localize(synth_dir, q, tmp_path, method: str, caplog) -> tuple[dict, str]:
    caplog.clear()
    out = stream(LocalizeConfig(method=method), synth_dir, Query(q), tmp_path / f"{method}.csv")
    return out.data, caplog.text


@pytest.mark.parametrize("shuffled", [False, True])
def test_a_query_not_in_capture_order_is_said(synth_dataset, synth_dir, tmp_path, caplog, shuffled):
    n = len(synth_dataset.query)
    rows = np.random.default_rng(0).permutation(n) if shuffled else np.arange(n)
    q = query_file(synth_dataset, tmp_path, rows)
    record, said = localize(synth_dir, q, tmp_path, "raw+seqmatch", caplog)
    warned = [w for w in record.get("warnings", []) if "jump around the map" in w]
    assert bool(warned) == shuffled, record.get("warnings")
    if shuffled:
        assert said.count("jump around the map") == 1 and "capture order" in warned[0] and "ls -v" in warned[0]
        assert f"of a map of {len(synth_dataset.reference)}" in warned[0]
        record, said = localize(synth_dir, q, tmp_path, "single", caplog)  # a single-frame method: order is nothing
        assert "jump around" not in said and not record.get("warnings")


def test_a_query_shorter_than_the_window_is_said(synth_dataset, synth_dir, tmp_path, caplog):
    q = query_file(synth_dataset, tmp_path, np.arange(10, 13))
    record, said = localize(synth_dir, q, tmp_path, "raw+seqmatch", caplog)
    line = "3 frames < L=5 (the window of the sequence method raw+seqmatch): no estimate; give at least 5 frames, " \
           "or --method single"
    assert record["warnings"] == [line] and said.count(line) == 1
    assert record["summary"]["answered"] == 0
    record, said = localize(synth_dir, q, tmp_path, "single", caplog)  # answers every frame: nothing to say
    assert record["summary"]["answered"] == 3 and not record.get("warnings")


def test_estimates_that_jump_on_a_query_in_order_are_not_called_disorder(synth_dataset, synth_dir, tmp_path, caplog):
    """The synthetic query's first 40 frames, in order: raw+vseqmatch (L=3) answers them jumping around the map (a
    noisy map), but consecutive query frames are alike: no word of capture order."""
    q = query_file(synth_dataset, tmp_path, np.arange(40))
    caplog.clear()
    out = stream(LocalizeConfig(method="raw+vseqmatch", seq_len=3), synth_dir, Query(q), tmp_path / "t.csv")
    est = [int(r["estimate"]) for r in csv.DictReader((tmp_path / "t.csv").open())]
    assert np.median(np.abs(np.diff([e for e in est if e >= 0]))) > 10  # the estimates do jump
    assert "jump around" not in caplog.text and not out.data.get("warnings")
