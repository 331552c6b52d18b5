"""A video query whose track covers only part of it: the frames outside the track have no ground truth, so they
are left out of every figure (R@1, AUC, R@100P) and their ``correct`` cell is empty; a frame known to have no
reference within the radius still counts as a wrong answer when accepted."""

from __future__ import annotations

import csv
import datetime
import json

import numpy as np
import pytest
from conftest import gps_videos, route, write_gpx

from seqnet.cli import main as cli_main
from seqnet.localize.localizer import Estimate
from seqnet.localize.replay import summarize
from seqnet.localize.trackfile import track_rows
from seqnet.metrics.precision_recall import pr_summary, precision_recall

T0 = datetime.datetime(2024, 5, 1, 10, 0, tzinfo=datetime.timezone.utc)
N = 40


def _estimates(rng, n):
    return [Estimate(frame=i, ref_index=int(rng.integers(-1, 5)) if i > 2 else -1, ref_frame=0, score=1.0,
                     confidence=float(rng.random()), latency_ms=1.0, full_window=i > 2,
                     ranked=np.zeros(0, np.int64), scores=np.zeros(0)) for i in range(n)]


def test_frames_without_truth_are_left_out_of_every_figure(rng):
    """The summary with ``known`` equals the summary of the known frames alone (a naive subset), and differs
    from counting the unknown frames as wrong answers (the old figures)."""
    n = 60
    est = _estimates(rng, n)
    correct, has = rng.random(n) < 0.6, rng.random(n) < 0.9
    known = rng.random(n) < 0.5
    correct &= has & known  # an unknown frame has no positive (its truth is not known)
    has &= known
    s = summarize(est, correct, has, known)
    idx = np.flatnonzero(known)
    alone = summarize([est[i] for i in idx], correct[idx], has[idx])
    for key in ("queries", "no_positive", "recall@1", "auc", "recall@100p"):
        assert s[key] == pytest.approx(alone[key]), key
    full = np.array([e.full_window for e in est])
    assert s["no_truth"] == int((full & ~known).sum())
    conf = np.array([e.confidence for e in est])
    old = pr_summary(*precision_recall(conf[full], correct[full], has[full])[:2])
    assert old["auc"] != pytest.approx(s["auc"])
    assert "no_truth" not in summarize(est, correct, has)  # without ``known``: as before


def test_correct_is_empty_where_the_truth_is_unknown(rng):
    est = _estimates(rng, 8)
    correct = np.array([0, 0, 0, 1, 0, 1, 0, 0], bool)
    known = np.array([1, 1, 1, 1, 1, 0, 0, 1], bool)
    rows = track_rows(est, None, None, correct, known=known)
    want = ["" if e.ref_index < 0 or not known[i] else str(int(correct[i])) for i, e in enumerate(est)]
    assert [str(r["correct"]) for r in rows] == want


@pytest.fixture
def videos(tmp_path):
    out = gps_videos(tmp_path, N, T0)
    lat, lon = route(N + 1)
    times = np.arange(N + 1) / 10
    half = 15  # 0 .. 1.4 s of a 4 s video: under half of it
    out["half.gpx"] = write_gpx(tmp_path / "half.gpx", T0, times[:half], lat[:half], lon[:half])
    assert cli_main(["-q", "dataset", "from-video", str(out["ref"]), str(out["query"]), "--out",
                     str(tmp_path / "ds"), "--method", "pixels", "--device", "cpu", "--ref-positions",
                     str(out["ref.gpx"]), "--query-positions", str(out["query.gpx"]), "--radius", "15"]) == 0
    return out


def _localize(videos, tmp_path, positions, out):
    assert cli_main(["-q", "localize", "--map", str(tmp_path / "ds"), "--query", str(videos["query"]), "--out",
                     str(tmp_path / out), "--method", "raw+seqmatch", "--seq-len", "3", "--device", "cpu",
                     "--positions", str(videos[positions])]) == 0
    rows = list(csv.DictReader((tmp_path / out).open()))
    return rows, json.loads((tmp_path / out).with_suffix(".json").read_text())["summary"]


def test_a_track_covering_half_the_video_scores_only_the_frames_it_places(videos, tmp_path):
    """The frames after the track's end were counted as accepted wrong answers (AUC and R@100P far too low) and
    written ``correct=0``; now they are left out, and the figures are those of the frames with a position."""
    rows, s = _localize(videos, tmp_path, "half.gpx", "half.csv")
    outside = [r for r in rows if r["true_x"] == ""]
    assert len(outside) == s["outside"] > 0 and all(r["correct"] == "" for r in outside)
    scored = [r for r in rows if r["full_window"] == "1" and r["true_x"] != ""]
    assert s["no_truth"] == sum(r["full_window"] == "1" for r in outside)
    conf = np.array([float(r["confidence"]) for r in scored])
    ok = np.array([r["correct"] == "1" for r in scored])
    has = np.array([r["correct"] != "" for r in scored])  # the map's route covers the whole track: all have one
    assert s["queries"] == int(has.sum()) and s["recall@1"] == pytest.approx(ok.mean())
    naive = pr_summary(*precision_recall(conf, ok, has)[:2])
    assert (s["auc"], s["recall@100p"]) == pytest.approx((naive["auc"], naive["recall@100p"]))


def test_a_full_track_has_every_frame_scored(videos, tmp_path):
    rows, s = _localize(videos, tmp_path, "query.gpx", "full.csv")
    assert s["outside"] == 0 and s["no_truth"] == 0
    assert all(r["correct"] != "" for r in rows if r["estimate"] != "-1")


def test_a_half_track_is_said_to_cover_half_and_per_metre_maps_localise_the_rest(videos, tmp_path, capsys):
    """A track of the video's first 1.4 s was said not to overlap it ("do not overlap the video's 0 .. 4.0 s"); on a map
    sampled per metre the frames after its end were neither localised nor counted (``outside: 0``). Now the
    line says what the track covers and how many frames it leaves out, and those frames are sampled by time at
    the rate kept along the track, localised and counted as ``outside``, as on a map sampled by time."""
    assert cli_main(["-q", "dataset", "from-video", str(videos["ref"]), str(videos["query"]), "--out",
                     str(tmp_path / "dsm"), "--method", "pixels", "--device", "cpu", "--ref-positions",
                     str(videos["ref.gpx"]), "--query-positions", str(videos["query.gpx"]), "--radius", "15",
                     "--every-metres", "20"]) == 0
    capsys.readouterr()
    rows, s = _localize(videos, tmp_path, "half.gpx", "h.csv")  # every frame (the map's own sampling)
    said = capsys.readouterr().err
    assert "do not overlap" not in said and "the track covers 0 .. 1.4 s of the video's 0 .. 4.0 s: the 25 " \
        "frames after its end have no position; they are localised" in said, said
    assert s["frames"] == N and s["outside"] == 25
    capsys.readouterr()
    (tmp_path / "ds").rename(tmp_path / "ds_every")
    (tmp_path / "dsm").rename(tmp_path / "ds")
    rows, s = _localize(videos, tmp_path, "half.gpx", "m.csv")
    said = capsys.readouterr().err
    assert "the 25 frames after its end have no position; with no track to measure metres on, those frames are " \
        "sampled by time at 5 frames/s (the rate one frame per 20 m kept along the track)" in said, said
    assert s["outside"] == 13 and s["frames"] == 8 + 13 and s["no_truth"] == sum(
        r["full_window"] == "1" and r["true_x"] == "" for r in rows)
    assert [float(r["name"]) for r in rows] == pytest.approx(np.r_[np.arange(0, 1.5, 0.2), np.arange(1.5, 4, 0.2)])
    capsys.readouterr()
    rows, s = _localize(videos, tmp_path, "query.gpx", "full.csv")  # a whole track: as before, silent
    assert s["frames"] == 20 and s["outside"] == 0 and not capsys.readouterr().err


def test_the_printed_summary_says_how_many_frames_have_no_known_position(videos, tmp_path, capsys):
    assert cli_main(["localize", "--map", str(tmp_path / "ds"), "--query", str(videos["query"]), "--out",
                     str(tmp_path / "p.csv"), "--method", "raw+seqmatch", "--seq-len", "3", "--device", "cpu",
                     "--positions", str(videos["half.gpx"])]) == 0
    s = json.loads((tmp_path / "p.json").read_text())["summary"]
    out = capsys.readouterr().out
    assert s["no_truth"] > 0 and f"({s['no_truth']} of them with no known position: not scored)" in out, out
