"""``seqnet localize --map MAP --query RUN.bag --topic T --positions-topic P``: a bag's positions as ground truth."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from conftest import bag_path, drive, write_bag

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.data.io import load_dataset
from seqnet.localize.truth import MapFrame, check_frame, same_frame

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
utm = pytest.importorskip("utm", reason="utm is not installed (pip install 'seqnet[ros]')")
TOPIC, START, PERIOD, OFFSET = "/camera/image_raw", 10**18, 10**8, 6 * 10**7  # positions 0.06 s after the images
LAT, LON, STEP, METRES = 63.43, 10.39, 1e-4, 10.0  # a place every STEP degrees north (~11 m) or METRES along x
TRUTH_TOPIC = {"fixes": "/gps/fix", "odometry": "/odom", "poses": "/pose"}


def positions(truth: str, places, lon: float = LON) -> dict:
    """write_bag's arguments for positions at ``places`` (place numbers) on the topic of ``truth``."""
    if truth == "fixes":
        return {"fixes": [(LAT + STEP * p, lon, 0) for p in places]}
    return {truth: [(METRES * p, 0.0) for p in places]}


def make_map(tmp_path, kind: str, truth: str):
    """A dataset of a 30-place drive (bag positions of ``truth``, 15 m radius) as the map."""
    ref = write_bag(bag_path(tmp_path, kind, "ref"), drive(30, 1), kind, start=START, period=PERIOD,
                    **positions(truth, range(30)))
    ds = tmp_path / "map"
    assert cli_main(["-q", "dataset", "from-images", str(ref), str(ref), "--topic", TOPIC, "--positions-topic",
                     TRUTH_TOPIC[truth], "--radius", "15", "--method", "pixels", "--patch", "4", "--out", str(ds),
                     "--device", "cpu"]) == 0
    return ds


def localize(tmp_path, ds, bag, *extra) -> int:
    return cli_main(["-q", "localize", "--map", str(ds), "--query", str(bag), "--topic", TOPIC, *extra,
                     "--method", "raw+seqmatch", "--seq-len", "3", "--out", str(tmp_path / "t.csv"),
                     "--device", "cpu"])


def naive_truth(rows, stamps, xy, ref_xy, radius):
    """The ``correct`` column by a plain loop: the position message nearest in time, within the radius."""
    out = []
    for row in rows:
        t = int(row["name"])
        j = min(range(len(stamps)), key=lambda j: abs(stamps[j] - t))
        est = int(row["estimate"])
        out.append("" if est < 0 else str(int(np.linalg.norm(xy[j] - ref_xy[est]) <= radius)))
    return out


@pytest.mark.parametrize(("kind", "truth", "map_truth"), [("ros1", "fixes", "fixes"), ("ros2", "fixes", "fixes"),
                                                          ("ros2", "odometry", "odometry"),
                                                          ("ros1", "poses", "odometry"), ("mcap", "poses", "odometry")])
def test_bag_positions_are_the_ground_truth_of_every_frame(tmp_path, kind, truth, map_truth, capsys):
    ds = make_map(tmp_path, kind, map_truth)
    places = [j + 5 + (4 if j % 4 == 0 else 0) for j in range(21)]  # every 4th position 4 places off the images
    bag = write_bag(bag_path(tmp_path, kind, "query"), drive(30, 2, noise=40)[5:25], kind, start=START,
                    period=PERIOD, position_offset=OFFSET, **positions(truth, places))
    assert localize(tmp_path, ds, bag, "--positions-topic", TRUTH_TOPIC[truth]) == 0
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    stamps = [START + OFFSET + j * PERIOD for j in range(len(places))]
    if truth == "fixes":
        xy = np.array([utm.from_latlon(LAT + STEP * p, LON)[:2] for p in places])
    else:
        xy = np.array([[METRES * p, 0.0] for p in places])
    want = naive_truth(rows, stamps, xy, load_dataset(ds).reference.positions, 15.0)
    assert [r["correct"] for r in rows] == want and {"0", "1"} <= set(want)  # right and wrong frames both
    full = [r["full_window"] == "1" for r in rows]
    summary = json.loads((tmp_path / "t.json").read_text())
    s = summary["summary"]
    assert s["queries"] == sum(full) and s["no_positive"] == 0
    assert s["recall@1"] == pytest.approx(np.mean([w == "1" for w, f in zip(want, full, strict=True) if f]))
    assert summary["inputs"]["positions_topic"] == TRUTH_TOPIC[truth]
    assert f"R@1 {s['recall@1']:.3f}" in capsys.readouterr().out


def test_an_index_map_carries_the_frame_of_its_dataset(tmp_path):
    ds = make_map(tmp_path, "ros2", "fixes")
    mp = tmp_path / "index"
    assert cli_main(["-q", "index", "build", "--dataset", str(ds), "--shortlist", "delta", "--rerank", "raw+seqmatch",
                     "--seq-len", "3", "--window", "causal", "--split", "all", "--device", "cpu",
                     "--out", str(mp)]) == 0
    assert json.loads((mp / "map.json").read_text())["source"]["positions_frame"] == "UTM zone 32V"
    places = [j + 5 + (4 if j % 4 == 0 else 0) for j in range(20)]
    bag = write_bag(bag_path(tmp_path, "ros2", "query"), drive(30, 2, noise=40)[5:25], "ros2", start=START,
                    period=PERIOD, **positions("fixes", places))
    assert localize(tmp_path, mp, bag, "--positions-topic", "/gps/fix") == 0
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    xy = np.array([utm.from_latlon(LAT + STEP * p, LON)[:2] for p in places])
    want = naive_truth(rows, [START + j * PERIOD for j in range(20)], xy, load_dataset(ds).reference.positions, 15)
    assert [r["correct"] for r in rows] == want and {"0", "1"} <= set(want)


def test_refusals_before_any_work(tmp_path, capsys):
    """Refused on the query's side before the map is read (a map that is not there is never reached)."""
    bag = write_bag(tmp_path / "q.bag", drive(20, 2), start=START, period=PERIOD, **positions("fixes", range(10)))
    (tmp_path / "images").mkdir()
    np.save(tmp_path / "q.npy", np.zeros((3, 4), np.float32))
    no_map = str(tmp_path / "no-map")
    out = ["--out", str(tmp_path / "t.csv")]
    query = ["--map", no_map, "--query", str(bag), "--topic", TOPIC]
    cases = [(["--dataset", no_map, *out, "--positions-topic", "/gps/fix"],
              "--positions-topic gives the ground truth of a ROS bag given as --query"),
             ([*query, *out, "--positions-tolerance", "1"], "--positions-tolerance goes with --positions-topic"),
             (["--map", no_map, "--query", str(tmp_path / "images"), *out, "--positions-topic", "/gps/fix"],
              "--positions-topic /gps/fix goes with a ROS bag"),
             (["--map", no_map, "--query", str(tmp_path / "q.npy"), *out, "--positions-topic", "/gps/fix"],
              "--positions-topic /gps/fix goes with a ROS bag as --query, but"),
             ([*query, *out, "--positions-topic", "/none"], "has no topic '/none'; its topics: /camera/image_raw "
              "(sensor_msgs/msg/Image, 20 messages), /gps/fix (sensor_msgs/msg/NavSatFix, 10 messages)"),
             ([*query, *out, "--positions-topic", TOPIC], "carries sensor_msgs/msg/Image, not a position message "
              "(sensor_msgs/msg/NavSatFix, nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped)"),
             ([*query, *out, "--positions-topic", "/gps/fix"], "5 of 20 images of the query bag"),
             ([*query, *out, "--positions-topic", "/gps/fix", "--positions-tolerance", "0.4"],
              "6 of 20 images of the query bag")]
    for args, msg in cases:
        assert cli_main(["localize", *args]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err and "no-map" not in err, err
        assert not (tmp_path / "t.csv").exists()


def test_positions_in_another_frame_than_the_map_are_refused(tmp_path, synth_dir, capsys):
    ds = make_map(tmp_path, "ros1", "fixes")
    bags = {name: write_bag(tmp_path / f"{name}.bag", drive(5, 2), start=START, period=PERIOD, **pos)
            for name, pos in (("odom", positions("odometry", range(5))),
                              ("zone33", positions("fixes", range(5), 16.0)))}
    meta = json.loads((ds / "dataset.json").read_text())
    assert meta["positions_frame"] == "UTM zone 32V"
    frames = shutil.copytree(ds, tmp_path / "frames")  # the map as if its positions were frame numbers
    (frames / "dataset.json").write_text(json.dumps({**meta, "position_unit": "frames"}))
    cases = [(ds, "odom", "/odom", "has positions in UTM zone 32V, the positions of /odom (odometry frame 'odom'): "
              "positions in two frames are not comparable"),
             (ds, "zone33", "/gps/fix", "the positions of /gps/fix (UTM zone 33V): positions in two frames"),
             (frames, "zone33", "/gps/fix", "has positions in frames, not metres"),
             (synth_dir, "zone33", "/gps/fix", "does not record the frame of its positions")]
    for mp, bag, topic, msg in cases:
        assert localize(tmp_path, mp, bags[bag], "--positions-topic", topic) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, err
        assert not (tmp_path / "t.csv").exists()


def test_frames_compare_by_utm_zone_and_hemisphere_or_by_name():
    assert same_frame("UTM zone 32V", "UTM zone 32W") and not same_frame("UTM zone 32V", "UTM zone 33V")
    assert not same_frame("UTM zone 32N", "UTM zone 32M")  # M: southern hemisphere, 10 000 km of northing apart
    assert not same_frame("UTM zone ?", "UTM zone ?") and not same_frame("UTM zone 32V", "odometry frame 'odom'")
    assert same_frame("odometry frame 'odom'", "odometry frame 'odom'")
    assert not same_frame("odometry frame 'odom'", "odometry frame 'map'")
    assert MapFrame.of({"position_unit": "metres", "positions_frame": 5}) == MapFrame("metres", None)
    check_frame(MapFrame.of({"position_unit": "metres", "positions_frame": "UTM zone 32U"}), "UTM zone 32V", "m", "/f")
    with pytest.raises(ConfigError, match="does not record the frame of its positions"):
        check_frame(MapFrame("metres", "UTM zone ?"), "UTM zone 32V", "m", "/f")  # a log without its zone


def test_a_track_in_x_y_metres_goes_with_a_map_of_unframed_metres(caplog):
    """A map built from an easting/northing CSV records no frame: a track in x, y metres is taken as in it (said),
    a lat/lon track (UTM) is refused with a hint a CSV user can follow."""
    from seqnet.sources.tracks.metres import XY_FRAME

    with caplog.at_level("WARNING", logger="seqnet"):
        check_frame(MapFrame("metres", None), XY_FRAME, "m", "t.csv")
    assert "taken to be in the map's frame, unchecked" in caplog.text
    with pytest.raises(ConfigError, match=r"give the track in the map's own metres .*lat,lon positions"):
        check_frame(MapFrame("metres", None), "UTM zone 32V", "m", "t.csv")
