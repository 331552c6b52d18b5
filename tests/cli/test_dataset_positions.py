"""Positions that make an unusable dataset are refused by every ``seqnet dataset from-...`` builder before anything
is written (one line, exit 2, naming the likely cause: easting/northing or lat/lon swapped, a radius in another unit);
few queries with a true match is one warning line; a lat/lon positions CSV is UTM metres in from-csv and from-images;
each command says what it wrote once."""

from __future__ import annotations

import datetime
import json

import numpy as np
import pytest
from conftest import drive, route, write_gpx, write_video
from PIL import Image

from seqnet.cli import main
from seqnet.data.io import load_dataset
from seqnet.metrics.summary import summarize_dataset

N = 20
EAST, NORTH = 500000.0, 6000000.0


def east_north(i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A route 10 m a step along the easting, drifting north."""
    return EAST + 10.0 * i, NORTH + 0.5 * i


def write_positions(path, side: str, cols: tuple[np.ndarray, np.ndarray], header: str = "easting,northing"):
    path.write_text(f"name,{header}\n" + "".join(f"{side}{i}.png,{a:.9f},{b:.9f}\n"
                                                  for i, (a, b) in enumerate(zip(*cols, strict=True))))
    return path


@pytest.fixture
def csvs(tmp_path):
    """Reference and query positions (query 3 m off the reference) and descriptors for from-csv."""
    rng = np.random.default_rng(0)
    i = np.arange(N, dtype=np.float64)
    e, n = east_north(i)
    for side, off in (("r", 0.0), ("q", 3.0)):
        write_positions(tmp_path / f"{side}.csv", side, (e + off, n))
        np.save(tmp_path / f"{side}.npy", rng.random((N, 4)).astype(np.float32))
        (tmp_path / f"{side}.names.txt").write_text("".join(f"{side}{i}.png\n" for i in range(N)))  # read by name
    write_positions(tmp_path / "q_swapped.csv", "q", (n, e + 3.0))  # easting and northing swapped in the query
    return tmp_path


def from_csv(d, ref: str, query: str, radius: str, out: str = "ds") -> int:
    return main(["dataset", "from-csv", "--ref-csv", str(d / ref), "--ref-desc", str(d / "r.npy"), "--query-csv",
                 str(d / query), "--query-desc", str(d / "q.npy"), "--radius", radius, "--out", str(d / out)])


def test_swapped_easting_northing_is_refused_and_nothing_written(csvs, capsys):
    assert from_csv(csvs, "r.csv", "q_swapped.csv", "25") == 2
    err = capsys.readouterr().err
    assert err.startswith("seqnet dataset from-csv: error: ds: none of the 20 queries has a reference within the "
                          "radius 25 metres, so every Recall@K would be undefined; nothing written: the nearest "
                          "reference to any query is ")
    assert ("with one traverse's two position columns swapped 20 of 20 queries would have one: easting/northing "
            "(or x/y, lat/lon) swapped in the reference's or the query's positions?") in err
    assert err.count("\n") == 1 and not (csvs / "ds").exists()


def test_a_radius_in_another_unit_is_refused_with_the_distances(csvs, capsys):
    assert from_csv(csvs, "r.csv", "q.csv", "0.0002") == 2  # meant as degrees; positions are metres 3 m apart
    err = capsys.readouterr().err
    assert ("none of the 20 queries has a reference within the radius 0.0002 metres, so every Recall@K would be "
            "undefined; nothing written: the nearest reference to any query is 3.0 metres away (median over the "
            "queries 3.0 metres), the radius is 0.0002 metres: positions swapped (easting/northing, lat/lon), the "
            "radius in another unit, or traverses in different coordinate frames?") in err
    assert not (csvs / "ds").exists()


def test_few_matches_are_one_warning_and_wrote_is_said_once(csvs, capsys):
    e, n = east_north(np.arange(N, dtype=np.float64))
    write_positions(csvs / "q_far.csv", "q", (e + np.where(np.arange(N) < 6, 3.0, 1000.0), n))  # 14 of 20 far off
    assert from_csv(csvs, "r.csv", "q_far.csv", "25") == 0
    out, err = capsys.readouterr()
    assert "ds: only 6 of 20 queries (30%) have a reference within the radius 25 metres: the nearest reference" in err
    assert [line for line in (out + err).splitlines() if "wrote" in line] == [
        f"wrote {csvs / 'ds'}: reference 20 and query 20 images, D=4, radius 25 metres, 6 queries with a true match, "
        "splits: none"]  # once (the library's own 'wrote dataset' line was said too)
    assert from_csv(csvs, "r.csv", "q.csv", "25", "ok") == 0
    assert "queries (" not in capsys.readouterr().err  # every query has a match: no warning


def latlon(i: np.ndarray, north_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A route near 66 N, 14 E, 10 m a step (northing), ``north_m`` metres further north."""
    return 66.0 + (10.0 * i + north_m) / 111320.0, 14.0 + 1e-6 * i


def test_from_csv_reads_lat_lon_as_utm_metres_and_refuses_them_swapped(csvs, capsys):
    i = np.arange(N, dtype=np.float64)
    write_positions(csvs / "rl.csv", "r", latlon(i), "lat,lon")
    write_positions(csvs / "ql.csv", "q", latlon(i, 3.0), "latitude,longitude")
    assert from_csv(csvs, "rl.csv", "ql.csv", "5") == 0
    ds = load_dataset(csvs / "ds")
    assert ds.position_unit == "metres" and ds.extra["positions_frame"] == "UTM zone 33W"
    steps = np.linalg.norm(np.diff(ds.reference.positions, axis=0), axis=1)
    np.testing.assert_allclose(steps, 10.0, rtol=0.01)  # metres along the route
    np.testing.assert_allclose(np.linalg.norm(ds.query.positions - ds.reference.positions, axis=1), 3.0, atol=0.1)
    assert summarize_dataset(ds)["queries_with_match"] == N
    capsys.readouterr()
    write_positions(csvs / "ql_swapped.csv", "q", latlon(i, 3.0)[::-1], "lat,lon")  # lon values under lat
    assert from_csv(csvs, "rl.csv", "ql_swapped.csv", "5", "sw") == 2
    assert capsys.readouterr().err == (
        f"seqnet dataset from-csv: error: the lat and lon columns of {csvs / 'rl.csv'} or of "
        f"{csvs / 'ql_swapped.csv'} look swapped: as given their positions lie 52.0 degrees apart, with one file's two "
        "columns swapped they meet; hint: swap the two column names in the header of the wrong one\n")
    write_positions(csvs / "ql_range.csv", "q", (np.full(N, 120.0), np.full(N, 66.0)), "lat,lon")
    assert from_csv(csvs, "rl.csv", "ql_range.csv", "5", "sw") == 2
    assert capsys.readouterr().err == (
        f"seqnet dataset from-csv: error: {csvs / 'ql_range.csv'}, line 2: latitude 120, longitude 66 out of range "
        "(latitude -90..90, longitude -180..180 degrees); hint: the lat and lon columns are swapped (every longitude "
        "is a valid latitude): swap their names in the header\n")
    assert not (csvs / "sw").exists()


@pytest.fixture
def folders(tmp_path):
    rng = np.random.default_rng(2)
    for side in ("r", "q"):
        (tmp_path / side).mkdir()
        for k in range(N):
            Image.fromarray((rng.random((8, 8)) * 255).astype(np.uint8)).save(tmp_path / side / f"{side}{k}.png")
    return tmp_path


def from_images(d, ref_csv: str, query_csv: str, radius: str, out: str = "ds") -> int:
    return main(["dataset", "from-images", str(d / "r"), str(d / "q"), "--method", "pixels", "--patch", "0",
                 "--ref-csv", str(d / ref_csv), "--query-csv", str(d / query_csv), "--radius", radius,
                 "--out", str(d / out)])


def test_from_images_reads_lat_lon_and_refuses_swapped_positions_before_describing(folders, capsys):
    i = np.arange(N, dtype=np.float64)
    write_positions(folders / "rl.csv", "r", latlon(i), "lat,lon")
    write_positions(folders / "ql.csv", "q", latlon(i[::-1], 3.0), "lat,lon")  # query driven the other way
    assert from_images(folders, "rl.csv", "ql.csv", "5") == 0
    out = capsys.readouterr().out
    assert out.count("wrote") == 1 and "ground truth csv, radius 5 metres" in out
    ds = load_dataset(folders / "ds")
    assert ds.position_unit == "metres" and ds.extra["positions_frame"] == "UTM zone 33W"
    np.testing.assert_allclose(np.linalg.norm(np.diff(ds.reference.positions, axis=0), axis=1), 10.0, rtol=0.01)
    near = np.linalg.norm(ds.query.positions[:, None] - ds.reference.positions[None], axis=2)
    assert (near.argmin(axis=1) == i[::-1]).all() and np.allclose(near.min(axis=1), 3.0, atol=0.1)
    assert summarize_dataset(ds)["queries_with_match"] == N  # each query's positive: the reference at its place
    e, n = east_north(i)
    write_positions(folders / "r.csv", "r", (e, n))
    write_positions(folders / "q.csv", "q", (n, e))
    assert from_images(folders, "r.csv", "q.csv", "25", "sw") == 2
    err = capsys.readouterr().err
    assert err.startswith("seqnet dataset from-images: error: sw: none of the 20 queries has a reference within the "
                          "radius 25 metres") and "position columns swapped 20 of 20 queries would have one" in err
    assert "describing" not in err  # refused before any image is described
    assert not (folders / "sw").exists()


T0 = datetime.datetime(2024, 5, 1, 10, 0, tzinfo=datetime.timezone.utc)
V = 30


@pytest.fixture
def videos(tmp_path):
    lat, lon = route(V + 1)
    times = np.arange(V + 1) / 10
    for side, seed, noise in (("ref", 1, 0), ("query", 2, 12)):
        write_video(tmp_path / f"{side}.mp4", drive(V, seed, noise), rate=10, creation_time=T0.isoformat())
    write_gpx(tmp_path / "ref.gpx", T0, times, lat, lon)
    write_gpx(tmp_path / "near.gpx", T0, times, lat + 5.0 / 111320.0, lon)  # 5 m north of the reference
    write_gpx(tmp_path / "far.gpx", T0, times, lat + 0.05, lon)  # 5.6 km north: another road
    return tmp_path


def from_video(d, query_track: str, out: str, *extra: str) -> int:
    return main(["dataset", "from-video", str(d / "ref.mp4"), str(d / "query.mp4"), "--out", str(d / out),
                 "--method", "pixels", "--device", "cpu", "--ref-positions", str(d / "ref.gpx"),
                 "--query-positions", str(d / query_track), *extra])


def test_from_video_refuses_a_track_elsewhere_and_a_radius_in_degrees(videos, capsys):
    assert from_video(videos, "far.gpx", "far") == 2
    err = capsys.readouterr().err
    assert err.startswith("seqnet dataset from-video: error: far: none of the 30 queries has a reference within the "
                          "radius 25 metres, so every Recall@K would be undefined; nothing written: the nearest "
                          "reference to any query is 5391.2 metres away") and err.count("\n") == 1
    assert from_video(videos, "near.gpx", "deg", "--radius", "0.0002") == 2
    assert "the nearest reference to any query is 5.0 metres away" in capsys.readouterr().err
    assert not (videos / "far").exists() and not (videos / "deg").exists()
    assert from_video(videos, "near.gpx", "ok", "--radius", "15") == 0
    out = capsys.readouterr().out
    assert out.count("wrote") == 1
    meta = json.loads((videos / "ok" / "dataset.json").read_text())
    assert meta["positions_frame"] == "UTM zone 33W"


def test_resample_says_wrote_once_and_warns_when_thinning_loses_matches(csvs, capsys):
    assert from_csv(csvs, "r.csv", "q.csv", "5") == 0
    capsys.readouterr()
    assert main(["dataset", "resample", str(csvs / "ds"), "--every", "4", "--side", "reference", "--out",
                 str(csvs / "thin")]) == 0  # a reference every 40 m, radius 5: a query in four keeps its match
    out, err = capsys.readouterr()
    assert [line for line in (out + err).splitlines() if "wrote" in line] == [
        f"wrote {csvs / 'thin'}: 5 reference / 20 query frames (from 20 / 20, every 4th frame of the reference side)"]
    assert "ds-every4: only 5 of 20 queries (25%) have a reference within the radius 5 metres" in err
