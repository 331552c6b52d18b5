"""The track file's ground-truth columns: each frame's true position and its estimate's error, last."""

from __future__ import annotations

import csv
import json
import math

import numpy as np

from seqnet.localize.localizer import Estimate
from seqnet.localize.trackfile import (
    TRACK_COLUMNS,
    TRUTH_COLUMNS,
    FrameTruth,
    check_output,
    track_rows,
    write_track,
)


def estimates(refs):
    return [Estimate(frame=i, ref_index=r, ref_frame=max(r, 0), score=1.0, confidence=0.5, latency_ms=1.0,
                     full_window=r >= 0, ranked=np.zeros(0, np.int64), scores=np.zeros(0))
            for i, r in enumerate(refs)]


def test_truth_columns_come_last_with_errors_and_json_has_no_nan(tmp_path):
    q_pos = np.array([[0.0, 0.0], [10.0, 0.0], [np.nan, np.nan], [30.0, 4.0]])
    r_pos = np.array([[0.0, 0.0], [13.0, 4.0], [30.0, 0.0]])
    truth = FrameTruth.of(q_pos, r_pos, np.array([-1, 1, 2, 2]), "metres")
    np.testing.assert_allclose(truth.error, [np.nan, 5.0, np.nan, 4.0])
    out = tmp_path / "t.csv"
    rows = track_rows(estimates([-1, 1, 2, 2]), None, None, np.array([0, 1, 0, 1], bool), truth=truth)
    write_track(check_output(out), rows, {"truth": truth.record()})
    read = list(csv.DictReader(out.open()))
    assert tuple(read[0]) == (*TRACK_COLUMNS, *TRUTH_COLUMNS)
    assert [(r["true_x"], r["true_y"], r["error"]) for r in read] == [
        ("0.000", "0.000", ""), ("10.000", "0.000", "5.000"), ("", "", ""), ("30.000", "4.000", "4.000")]
    text = (tmp_path / "t.json").read_text()
    assert "NaN" not in text
    record = json.loads(text)["truth"]
    assert record["errors"] == [None, 5.0, None, 4.0] and record["true_positions"][2] is None
    assert record["unit"] == "metres" and record["frames_with_error"] == 2 and math.isclose(record["error_median"], 4.5)
    check_output(out)  # a track with truth columns is still ours: replaceable


def test_no_positions_no_truth():
    assert FrameTruth.of(None, np.zeros((3, 2)), np.array([0, 1]), "metres") is None
    one = FrameTruth.of(np.array([[4.0]]), np.array([[1.0]]), np.array([0]), "frames")
    assert one.cells(0) == {"true_x": "4.000", "true_y": "", "error": "3.000"}
