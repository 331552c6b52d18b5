"""The video commands end to end: ``dataset from-video``, ``describe VIDEO``, ``localize --query VIDEO`` (with
--positions, --plot, --realtime); a bad video or track is one line on stderr, exit 2, nothing left behind."""

from __future__ import annotations

import datetime
import json
import time

import numpy as np
import pytest
from conftest import drive, gps_videos, route, write_gpx, write_video

from seqnet.cli import main as cli_main

T0 = datetime.datetime(2024, 5, 1, 10, 0, tzinfo=datetime.timezone.utc)
N = 30


@pytest.fixture
def videos(tmp_path):
    return gps_videos(tmp_path, N, T0)


def _dataset(videos, out, *extra):
    return cli_main(["-q", "dataset", "from-video", str(videos["ref"]), str(videos["query"]), "--out", str(out),
                     "--method", "pixels", "--device", "cpu", "--ref-positions", str(videos["ref.gpx"]),
                     "--query-positions", str(videos["query.gpx"]), *extra])


def test_from_video_then_localize_with_a_plot(videos, tmp_path, capsys):
    assert _dataset(videos, tmp_path / "ds", "--radius", "15") == 0
    assert "reference: 30 of 30 frames kept" in capsys.readouterr().out
    track, png = tmp_path / "track.csv", tmp_path / "track.png"
    assert cli_main(["localize", "--map", str(tmp_path / "ds"), "--query", str(videos["query"]), "--positions",
                     str(videos["query.gpx"]), "--out", str(track), "--plot", str(png), "--method", "raw+seqmatch",
                     "--seq-len", "3", "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "30 frames decoded, 0 dropped" in printed and "R@1" in printed
    s = json.loads(track.with_suffix(".json").read_text())["summary"]
    assert s["recall@1"] > 0.8 and s["dropped"] == 0 and s["outside"] == 0
    assert {"decode_ms", "describe_ms", "latency_ms", "decode_share"} <= set(s)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_describe_a_video(videos, tmp_path, capsys):
    out = tmp_path / "d.npy"
    assert cli_main(["-q", "describe", str(videos["query"]), "--method", "pixels", "--fps", "5", "--out", str(out),
                     "--device", "cpu"]) == 0
    assert np.load(out).shape[0] == 15
    assert (tmp_path / "d.names.txt").read_text().split()[:2] == ["0.000000", "0.200000"]
    assert cli_main(["describe", str(tmp_path), "--method", "pixels", "--fps", "5", "--out", str(out)]) == 2
    assert "goes with a video file" in capsys.readouterr().err


def test_realtime_takes_the_video_duration(videos, tmp_path, capsys):
    assert _dataset(videos, tmp_path / "ds") == 0
    short = write_video(tmp_path / "short.mp4", drive(N, 2, 12)[:12], rate=10)
    t0 = time.monotonic()
    assert cli_main(["-q", "localize", "--map", str(tmp_path / "ds"), "--query", str(short), "--realtime",
                     "--out", str(tmp_path / "t.csv"), "--method", "single", "--device", "cpu"]) == 0
    assert 1.1 < time.monotonic() - t0 < 6  # 12 frames at 10 fps: 1.1 s of video
    s = json.loads((tmp_path / "t.json").read_text())["summary"]
    assert s["decoded"] == 12 and s["frames"] + s["dropped"] == 12


@pytest.mark.parametrize("case", ["empty", "text", "truncated", "another day", "no overlap", "no truth"])
def test_bad_inputs_are_one_line(videos, tmp_path, capsys, case):
    args = {"ref": videos["ref"], "ref.gpx": videos["ref.gpx"]}
    bad = tmp_path / "bad.mp4"
    if case in ("empty", "text", "truncated"):
        data = videos["ref"].read_bytes()
        bad.write_bytes({"empty": b"", "text": b"no video here\n" * 50, "truncated": data[: len(data) // 4]}[case])
        args["ref"] = bad
    elif case != "no truth":
        lat, lon = route(N)
        shift = datetime.timedelta(days=3) if case == "another day" else datetime.timedelta(hours=3)
        args["ref.gpx"] = write_gpx(tmp_path / "other.gpx", T0 + shift, np.arange(N) / 10, lat, lon)
    out = tmp_path / "ds"
    extra = [] if case == "no truth" else ["--ref-positions", str(args["ref.gpx"]), "--query-positions",
                                           str(videos["query.gpx"])]
    rc = cli_main(["dataset", "from-video", str(args["ref"]), str(videos["query"]), "--out", str(out), "--method",
                   "pixels", *extra])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert {"another day": "another day", "no overlap": "does not overlap", "no truth": "ground truth is needed"}.get(
        case, "video") in err
    assert not out.exists()


def test_report_places_the_queries_and_shows_pairs_from_the_videos(videos, tmp_path):
    assert _dataset(videos, tmp_path / "ds", "--radius", "15") == 0
    assert cli_main(["-q", "eval", "--dataset", str(tmp_path / "ds"), "--method", "single", "--out",
                     str(tmp_path / "ev"), "--report", "--images-query", str(videos["query"]), "--images-ref",
                     str(videos["ref"]), "--device", "cpu"]) == 0
    page = (tmp_path / "ev" / "report.html").read_text()
    assert '<section id="trajectory">' in page and '<section id="pairs">' in page
    pairs = page.split('<section id="pairs">')[1]
    assert "best: query" in pairs and "pictures left out" not in pairs and pairs.count("data:image/png") >= 4


def test_aligned_videos_keeping_different_counts_are_refused_and_checked(tmp_path, capsys):
    """``--aligned --fps 5`` on a 3 s video (10 fps) and a 1.2 s one (25 fps) keeps 15 and 6 frames: refused in one
    line naming --fps, nothing written (it used to log a line and pair frame i with frame i). ``dataset check``
    refuses such a dataset written before, recorded as ``"ground_truth": "aligned"``."""
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse

    slow = write_video(tmp_path / "slow.mp4", drive(N, 1), rate=10)
    fast = write_video(tmp_path / "fast.mp4", drive(N, 2, 12), rate=25)
    out = tmp_path / "ds"
    rc = cli_main(["dataset", "from-video", str(slow), str(fast), "--method", "pixels", "--aligned", "--fps", "5",
                   "--radius", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and not out.exists(), err
    assert ("--aligned: query frame i is the place of reference frame i, but the reference keeps 15 frames and the "
            "query 6: --fps 5 keeps frames in proportion to each video's length (3.0 s and 1.2 s), so videos of "
            "different frame rates or lengths keep different counts") in err
    assert "hint: give positions for both videos (--ref-positions / --query-positions FILE" in err
    short = write_video(tmp_path / "short.mp4", drive(N - 10, 2, 12), rate=25)
    rc = cli_main(["dataset", "from-video", str(slow), str(short), "--method", "pixels", "--aligned", "--out",
                   str(out)])
    assert rc == 2 and "every frame is kept (30 frames at 10 fps, 20 at 25 fps)" in capsys.readouterr().err
    rc = cli_main(["dataset", "from-video", str(slow), str(fast), "--method", "pixels", "--aligned", "--out", str(out)])
    assert rc == 0 and out.exists()  # 30 and 30 frames: as many, so frame i pairs with frame i (the user's claim)
    capsys.readouterr()
    desc = np.random.default_rng(0).random((15, 8)).astype(np.float32)
    ref, qry = (Traverse(d, np.arange(len(d), dtype=float)[:, None], [f"{i / r:.6f}" for i in range(len(d))], name=n)
                for d, r, n in ((desc, 5, "reference"), (desc[:6], 5, "query")))
    save_dataset(Dataset(ref, qry, 1.0, name="old", extra={"ground_truth": "aligned"}), tmp_path / "old")
    assert cli_main(["dataset", "check", str(tmp_path / "old")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("seqnet dataset check: error: old: frame-aligned ground truth: query frame i is the place "
                          "of reference frame i, but the reference has 15 images and the query 6") and \
        len(err.strip().splitlines()) == 1, err


def _localize(videos, tmp_path, ds, *extra, positions=None, out="t.csv"):
    return cli_main(["localize", "--map", str(tmp_path / ds), "--query", str(videos["query"]), "--out",
                     str(tmp_path / out), "--method", "raw+seqmatch", "--seq-len", "3", "--device", "cpu",
                     "--positions", str(positions or videos["query.gpx"]), *extra])


def test_localize_samples_the_query_as_the_map_was(videos, tmp_path, capsys):
    """A map keeping 5 of the video's 10 frames/s (or one frame per 20 m) localises the query at that rate by
    default, as eval scores it; another rate is warned."""
    assert _dataset(videos, tmp_path / "ds5", "--radius", "15", "--fps", "5") == 0
    assert _dataset(videos, tmp_path / "dsm", "--radius", "15", "--every-metres", "20") == 0
    capsys.readouterr()
    assert _localize(videos, tmp_path, "ds5") == 0
    out = capsys.readouterr().out
    s = json.loads((tmp_path / "t.json").read_text())["summary"]
    assert s["frames"] == 15 and s["sampling"] == {"fps": 5.0, "every_metres": None, "as": "map"}
    assert "(5 frames/s, as the map)" in out and s["recall@1"] > 0.8
    assert _localize(videos, tmp_path, "dsm") == 0
    s = json.loads((tmp_path / "t.json").read_text())["summary"]
    kept = json.loads((tmp_path / "dsm" / "dataset.json").read_text())
    assert s["frames"] == 15 and s["sampling"]["every_metres"] == 20  # 10 m per frame: every other frame
    assert "one frame per 20 m, as the map" in capsys.readouterr().out and kept["sampling"]["every_metres"] == 20
    assert _localize(videos, tmp_path, "ds5", "--fps", "10") == 0
    err = capsys.readouterr().err
    assert "the map keeps 5 frames/s of its video, this query 10 frames/s" in err and "hint: --fps 5" in err
    assert json.loads((tmp_path / "t.json").read_text())["summary"]["frames"] == 30


def test_a_track_placing_nothing_is_refused_before_any_frame(videos, tmp_path, capsys):
    """A track in milliseconds, or with latitude and longitude swapped, places no frame near the map: one line,
    exit 2, no track written (it said "this is a bug" after localising every frame)."""
    from conftest import write_track_csv

    assert _dataset(videos, tmp_path / "ds", "--radius", "15") == 0
    lat, lon = route(N + 1)
    times = np.arange(N + 1) / 10
    bad = {"ms": write_track_csv(tmp_path / "ms.csv", times * 1000, lat, lon),
           "swapped": write_track_csv(tmp_path / "sw.csv", times, lon, lat)}
    capsys.readouterr()
    for case, text in (("ms", "times in milliseconds?"), ("swapped", "latitude and longitude swapped")):
        assert _localize(videos, tmp_path, "ds", positions=bad[case], out=f"track_{case}.csv") == 2
        err = capsys.readouterr().err
        assert text in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / f"track_{case}.csv").exists()
    rc = cli_main(["dataset", "from-video", str(videos["ref"]), str(videos["query"]), "--out", str(tmp_path / "dm"),
                   "--method", "pixels", "--ref-positions", str(videos["ref.gpx"]), "--query-positions",
                   str(bad["ms"])])
    assert rc == 2 and "times in milliseconds?" in capsys.readouterr().err and not (tmp_path / "dm").exists()


def test_a_video_clock_off_by_seconds_is_said(videos, tmp_path, capsys):
    assert _dataset(videos, tmp_path / "ds", "--radius", "15") == 0
    capsys.readouterr()
    late = (T0 + datetime.timedelta(seconds=1.5)).isoformat()
    assert _localize(videos, tmp_path, "ds", "--video-start", late) == 0
    err = capsys.readouterr().err
    assert "the estimates run 1.5 s behind the track" in err and "--video-start" in err
    assert _localize(videos, tmp_path, "ds") == 0
    assert "the estimates run" not in capsys.readouterr().err


def test_from_video_takes_splits_of_the_kept_frames(videos, tmp_path):
    from seqnet.data.io import load_dataset

    assert _dataset(videos, tmp_path / "ds", "--split", "train=0:15", "--split", "test=15:30") == 0
    ds = load_dataset(tmp_path / "ds")
    assert set(ds.splits) == {"train", "test"} and len(ds.split("test").query) == 15
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text())["videos"]["query"]["stream"] == 0


def test_localize_stream_picks_a_video_stream(videos, tmp_path, capsys):
    assert _dataset(videos, tmp_path / "ds") == 0
    rc = cli_main(["localize", "--map", str(tmp_path / "ds"), "--query", str(videos["query"]), "--stream", "1",
                   "--out", str(tmp_path / "t.csv"), "--method", "single"])
    err = capsys.readouterr().err
    assert rc == 2 and "--stream 1: video stream 1 of" in err and "holds 1 video stream (0: 32x16)" in err, err
    assert cli_main(["-q", "localize", "--map", str(tmp_path / "ds"), "--query", str(videos["query"]), "--stream",
                     "0", "--out", str(tmp_path / "t.csv"), "--method", "single"]) == 0
