"""``seqnet dataset from-video``: Nordland64 frames written as videos (+ GPX / NMEA / CSV tracks) give the dataset
the same frames give as PNG files; frames outside a track are dropped; --every-metres and --aligned."""

from __future__ import annotations

import datetime
import logging

import numpy as np
import pytest
from conftest import route, shared_data, write_gpx, write_nmea, write_track_csv, write_video

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.data.io import load_dataset
from seqnet.describe import DescribeConfig
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.pipelines.from_images import FromImagesConfig
from seqnet.pipelines.from_images import main as from_images
from seqnet.pipelines.from_video import FromVideoConfig, main
from seqnet.sources.placed import place_video

N = 160
T_REF = datetime.datetime(2024, 5, 1, 10, 0, tzinfo=datetime.timezone.utc)
T_QRY = datetime.datetime(2024, 12, 2, 9, 30, tzinfo=datetime.timezone.utc)
METHODS = ("single", "raw+seqmatch")
PIXELS = DescribeConfig(method="pixels", device="cpu")


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Summer frames as a 10 fps reference video, winter frames as a variable-speed query video, their tracks
    (place i 10 m after place i - 1), and both as PNG folders (links)."""
    from PIL import Image

    root = shared_data("nordland64")
    d = tmp_path_factory.mktemp("videos")
    names = sorted(p.name for p in (root / "summer").iterdir())[:N]
    q_times = np.cumsum(np.random.default_rng(0).uniform(0.04, 0.3, N))
    q_times -= q_times[0]
    out = {"q_times": q_times}
    for season, t0, times in (("summer", T_REF, np.arange(N) / 10), ("winter", T_QRY, q_times)):
        frames = [np.asarray(Image.open(root / season / n).convert("RGB")) for n in names]
        out[season] = write_video(d / f"{season}.mp4", frames, times=times, creation_time=t0.isoformat())
        (d / season).mkdir()
        for n in names:
            (d / season / n).symlink_to(root / season / n)
        lat, lon = route(N + 1)  # the logs run a little past the video (NMEA: hundredths of a second)
        track = np.append(times, times[-1] + 0.1)
        out[f"{season}.gpx"] = write_gpx(d / f"{season}.gpx", t0, track, lat, lon)
        out[f"{season}.nmea"] = write_nmea(d / f"{season}.nmea", t0, track, lat, lon)
        out[f"{season}.csv"] = write_track_csv(d / f"{season}.csv", track, lat, lon)
    out["dir"] = d
    return out


def recalls(path) -> dict[str, float]:
    ev = evaluate(load_dataset(path), EvalConfig(methods=METHODS, device="cpu"))
    return {m: ev.results["methods"][m]["recall@1"] for m in METHODS}


def test_videos_give_what_their_frames_give(drives, tmp_path):
    png = from_images(FromImagesConfig(describe=PIXELS, ground_truth="frames", radius=2.0),
                      drives["dir"] / "summer", drives["dir"] / "winter", tmp_path / "png")
    out = main(FromVideoConfig(describe=PIXELS, radius=25.0), drives["summer"], drives["winter"], tmp_path / "gpx",
               (drives["summer.gpx"], drives["winter.gpx"]))
    ds = load_dataset(out)
    assert len(ds.reference) == len(ds.query) == N and ds.position_unit == "metres"
    assert ds.extra["positions_frame"] == "UTM zone 33W"
    assert ds.query.names[1] == f"{round(drives['q_times'][1], 3):.6f}"  # named by video time (ms in the file)
    got, want = recalls(out), recalls(png)
    for m in METHODS:
        assert abs(got[m] - want[m]) <= 0.05, (got, want)
    assert got["raw+seqmatch"] > got["single"] > 0.1  # sensible: sequences help on Nordland


def test_nmea_and_csv_place_frames_as_gpx_does(drives):
    placed = {fmt: place_video(drives["winter"], drives[f"winter.{fmt}"]) for fmt in ("gpx", "nmea", "csv")}
    assert {p.counts["kept"] for p in placed.values()} == {N} and placed["gpx"].frame == "UTM zone 33W"
    for fmt in ("nmea", "csv"):  # the same positions: the same dataset, the same recall
        tol = 3.0 if fmt == "nmea" else 1e-3  # NMEA times in hundredths of a second: up to 10 ms (2.5 m here) off
        np.testing.assert_allclose(placed[fmt].positions, placed["gpx"].positions, atol=tol)
    steps = np.linalg.norm(np.diff(placed["gpx"].positions, axis=0), axis=1)
    np.testing.assert_allclose(steps, 10.0, rtol=0.02)  # each frame at its place (video times in ms), speed varying


def test_every_metres_and_frames_outside_the_track(drives, tmp_path, caplog):
    lat, lon = route(N)
    half = write_gpx(tmp_path / "half.gpx", T_REF, np.arange(N // 2) / 10, lat[: N // 2], lon[: N // 2])
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        out = main(FromVideoConfig(describe=PIXELS, every_metres=20.0), drives["summer"], drives["winter"],
                   tmp_path / "ds", (half, drives["winter.gpx"]))
    (said,) = [r.getMessage() for r in caplog.records if "outside the track" in r.getMessage()]
    assert said.endswith(f"dropped (the track covers 0.0 .. {(N // 2 - 1) / 10:.1f} s of the video's 0 .. "
                         f"{N / 10:.1f} s)"), said  # which part: it said only how many
    ds = load_dataset(out)
    assert len(ds.reference) == N // 4 and len(ds.query) == N // 2  # 10 m spacing, one frame per 20 m
    assert ds.extra["videos"]["reference"]["frames"] == {"total": N, "outside": N // 2, "kept": N // 4}
    assert ds.extra["videos"]["query"]["stream"] == 0  # the video stream read, recorded
    steps = np.linalg.norm(np.diff(ds.query.positions, axis=0), axis=1)
    np.testing.assert_allclose(steps, 20.0, rtol=0.01)


def test_aligned_and_the_ground_truth_refusals(drives, tmp_path):
    out = main(FromVideoConfig(describe=PIXELS, aligned=True, radius=2.0, fps=5.0), drives["summer"],
               drives["summer"], tmp_path / "aligned")
    ds = load_dataset(out)
    assert ds.position_unit == "frames" and len(ds.reference) == N // 2 and ds.reference.names[1] == "0.200000"
    with pytest.raises(ConfigError, match="ground truth is needed"):
        main(FromVideoConfig(describe=PIXELS), drives["summer"], drives["winter"], tmp_path / "x")
    with pytest.raises(ConfigError, match="for both videos"):
        main(FromVideoConfig(describe=PIXELS), drives["summer"], drives["winter"], tmp_path / "x",
             (drives["summer.gpx"], None))
    with pytest.raises(DatasetError, match="another day"):  # the winter track against the summer video
        main(FromVideoConfig(describe=PIXELS), drives["summer"], drives["winter"], tmp_path / "x",
             (drives["winter.gpx"], drives["winter.gpx"]))
    assert not (tmp_path / "x").exists()


def test_eval_names_a_query_track_a_constant_time_off(drives, tmp_path, caplog):
    from seqnet.eval.evaluate import video_clock_note

    lat, lon = route(N + 1)
    times = np.append(drives["q_times"], drives["q_times"][-1] + 0.1)
    late = write_track_csv(tmp_path / "late.csv", times + 2.0, lat, lon)  # a logger that started counting 2 s late
    out = main(FromVideoConfig(describe=PIXELS, radius=15.0), drives["summer"], drives["winter"], tmp_path / "late",
               (drives["summer.csv"], late))
    ds = load_dataset(out)
    assert ds.extra["videos"]["query"]["track_times"] == "seconds"
    ev = evaluate(ds, EvalConfig(methods=METHODS, device="cpu"))
    note = video_clock_note(ev)
    assert note and "the query track runs 2.0 s late against the reference's (hint: subtract 2.0 s" in note, note
    good = main(FromVideoConfig(describe=PIXELS, radius=15.0), drives["summer"], drives["winter"], tmp_path / "good",
                (drives["summer.csv"], drives["winter.csv"]))
    assert video_clock_note(evaluate(load_dataset(good), EvalConfig(methods=METHODS, device="cpu"))) is None
