"""The map's own frames given as the query of ``localize --map``: a one-line note (it ran silently with every
answer trivially right); a query of other frames stays silent."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.cli import main as cli_main


def _noted(rows, query):
    from seqnet.localize.copies import CopyWatch

    watch = CopyWatch(rows)
    frames = list(watch.watch((q, 0.0) for q in query))
    assert len(frames) == len(query)  # the frames pass as they are
    return watch.note()


def test_the_note_compares_a_bounded_sample_row_for_row(rng):
    from seqnet.localize.copies import SAMPLE, CopyWatch

    rows = rng.standard_normal((100, 24)).astype(np.float32)
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    assert "the query frames are the map's own reference frames" in _noted(rows, rows)
    watch = CopyWatch(rows)
    list(watch.watch((q, 0.0) for q in rows))
    assert len(watch.sample) == SAMPLE  # bounded
    rounded = rows * (1 + 1e-7 * rng.standard_normal(rows.shape)).astype(np.float32)  # an index map renormalised
    assert _noted(rounded, rows) is not None and _noted(rows.astype(np.float16), rows) is not None
    other = rows + 0.01 * rng.standard_normal(rows.shape).astype(np.float32)  # another traverse, close by
    assert _noted(rows, other) is None
    assert _noted(rows, rows[1:]) is None  # shifted: not row for row
    assert _noted(rows, rows[:2]) is None and _noted(None, rows) is None
    one_off = rows.copy()
    one_off[SAMPLE - 1] = rows[0]  # the last frame compared differs
    assert _noted(rows, one_off) is None
    black = rows.copy()
    black[:SAMPLE] = rows[0]  # two drives that both start with black (constant) frames: alike, not the same drive
    assert _noted(black, black.copy()) is None


@pytest.fixture
def index_map(synth_dir, tmp_path):
    assert cli_main(["-q", "index", "build", "--dataset", str(synth_dir), "--split", "all", "--window", "causal",
                     "--shortlist", "single", "--rerank", "raw+seqmatch", "--device", "cpu", "--out",
                     str(tmp_path / "map")]) == 0
    return tmp_path / "map"


@pytest.mark.parametrize("kind", ["dataset", "index"])
def test_the_maps_own_frames_as_the_query_are_said(synth_dir, index_map, tmp_path, capsys, kind):
    map_dir = synth_dir if kind == "dataset" else index_map
    capsys.readouterr()
    for side, said in (("reference", True), ("query", False)):
        assert cli_main(["localize", "--map", str(map_dir), "--query", str(synth_dir / side / "descriptors.npy"),
                         "--method", "raw+seqmatch", "--device", "cpu", "--out", str(tmp_path / f"{side}.csv")]) == 0
        err = capsys.readouterr().err
        assert ("the query frames are the map's own reference frames" in err) == said, err
        if said:
            assert len([line for line in err.splitlines() if "own reference frames" in line]) == 1
