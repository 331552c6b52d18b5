"""MSLS predictions files (seqnet.eval.msls_predictions) against the rules mapillary_sls's evaluate.py enforces: a row
for every query key it scores (image keys for im2im; comma-joined keys of L consecutive frames of one sequence, centred,
for seq2seq), equal widths (np.loadtxt), no prediction twice in a row, no query twice."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.data.msls import dataset_from_msls
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.eval.msls_predictions import _rows, msls_predictions

SEQS = {  # side -> (sequence key, frame number) of each row, in seq_info order
    "query": [("A", i) for i in range(7)] + [("B", f) for f in (0, 1, 2, 4, 5, 6)] + [("C", i) for i in range(2)],
    "database": [("D", i) for i in range(9)] + [("E", f) for f in (3, 4, 5, 7, 8)],
}


def write_city(root, seed=0):
    """A city (train_val/tiny) whose query and database hold sequences with a frame-number gap (B, E) and a short
    one (C), with descriptors that follow the place."""
    rng = np.random.default_rng(seed)
    base = root / "train_val" / "tiny"
    for side, rows in SEQS.items():
        folder = base / side
        (folder / "images").mkdir(parents=True)
        keys = [f"{side[0]}{s}{i:02d}" for i, (s, _) in enumerate(rows)]
        east = 400000.0 + 4.1 * np.arange(len(rows)) + (0.7 if side == "query" else 0.0)
        post = [f"{i},{k},{e:.2f},5000000.00,0,False,False,Forward"
                for i, (k, e) in enumerate(zip(keys, east, strict=True))]
        (folder / "postprocessed.csv").write_text(
            ",key,easting,northing,unique_cluster,control_panel,night,view_direction\n" + "\n".join(post) + "\n")
        seq = [f"{i},{k},{s},{f}" for i, (k, (s, f)) in enumerate(zip(keys, rows, strict=True))]
        (folder / "seq_info.csv").write_text(",key,sequence_key,frame_number\n" + "\n".join(seq) + "\n")
        for k in keys:
            (folder / "images" / f"{k}.jpg").write_bytes(b"")
        place = np.sin(np.outer(east - 400000.0, np.arange(1, 9) / 9.0))
        desc = (place + 0.3 * rng.standard_normal(place.shape)).astype(np.float32)
        np.save(root / f"{side}.npy", desc[np.argsort(keys)])  # the images folder's sorted order
    return dataset_from_msls(root, ["tiny"], [str(root / "database.npy")], [str(root / "query.npy")]).split("tiny")


def msls_keys(side: str, length: int) -> list[str]:
    """The keys MSLS's arange_as_seq makes, by a loop: for every row idx with a centred window of ``length``
    rows, the window's keys comma-joined when its rows share one sequence and their frame numbers rise by one."""
    rows = SEQS[side]
    keys = [f"{side[0]}{s}{i:02d}" for i, (s, _) in enumerate(rows)]
    out = []
    for idx in range(length // 2, len(rows) - length // 2):
        window = list(range(idx - length // 2, idx + length // 2 + 1))
        if all(rows[j][0] == rows[window[0]][0] and rows[j][1] == rows[window[0]][1] + t for t, j in enumerate(window)):
            out.append(",".join(keys[j] for j in window))
    return out


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    return write_city(tmp_path_factory.mktemp("msls"))


@pytest.mark.filterwarnings("ignore:Input line 1 contained no data")  # numpy: the '#' line
@pytest.mark.parametrize("method, task, length", [
    ("single", "im2im", 1), ("delta", "seq2seq", 3), ("raw+seqmatch", "seq2seq", 3),
    ("hvpr-single:raw+seqmatch", "seq2seq", 3), ("smoothing", "seq2seq", 5)])
def test_file_follows_evaluate_py_rules(city, tmp_path, method, task, length):
    seq_len = 5 if method == "smoothing" else 3
    ev = evaluate(city, EvalConfig(methods=(method,), seq_len=seq_len, device="cpu"))
    text = msls_predictions(ev)
    path = tmp_path / "pred.txt"
    path.write_text(text)
    assert text.splitlines()[0] == f"# seqnet {method}: mapillary_sls evaluate.py --task {task}" + (
        f" --seq-length {length}" if length > 1 else "")
    table = np.loadtxt(path, ndmin=2, dtype=str)  # as evaluate.py reads it: equal widths, '#' a comment
    q_keys, db_keys = msls_keys("query", length), msls_keys("database", length)
    assert sorted(table[:, 0]) == sorted(q_keys)  # a row for every key MSLS scores, and no other
    assert len(set(table[:, 0])) == len(table)
    assert table.shape[1] == 1 + min(20, len(db_keys))
    for row in table:
        assert len(set(row[1:])) == len(row) - 1 and set(row[1:]) <= set(db_keys)
        assert all(len(k.split(",")) == length for k in row)


def test_single_rows_for_every_query_image_beside_sequence_methods(city):
    """A single-frame method's im2im file has a row for every query image, also beside a sequence method."""
    ev = evaluate(city, EvalConfig(methods=("single", "delta"), seq_len=3, device="cpu"))
    one = dict(ev.__dict__, retrieved={"single": ev.retrieved["single"]})
    rows = [ln.split() for ln in msls_predictions(type(ev)(**one)).splitlines()[1:]]
    assert [r[0] for r in rows] == msls_keys("query", 1) and len(rows) == len(SEQS["query"])


def test_rows_equally_wide_and_refused_when_a_query_has_none(caplog):
    ranked = np.array([[3, 1, 2], [0, -1, -1], [2, 0, 1]])
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert _rows(ranked, 3, "m") == [[3], [0], [2]]
    assert "1 per query (not 3)" in caplog.text
    with pytest.raises(ConfigError, match="ranked no reference"):
        _rows(np.array([[1, 0], [-1, -1]]), 2, "m")


def test_windows_msls_cannot_read_are_refused(city):
    ev = evaluate(city, EvalConfig(methods=("raw+seqmatch",), seq_len=3, window="causal", device="cpu"))
    with pytest.raises(ConfigError, match="centred windows of an odd length"):
        msls_predictions(ev)
    ev = evaluate(city, EvalConfig(methods=("single", "delta"), seq_len=3, common_queries=True, device="cpu"))
    one = dict(ev.__dict__, retrieved={"single": ev.retrieved["single"]})
    with pytest.raises(ConfigError, match="needs a row for every query image"):
        msls_predictions(type(ev)(**one))
