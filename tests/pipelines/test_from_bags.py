"""``seqnet dataset from-images REF.bag QUERY.bag --topic T --positions-topic P``: a bag traverse as a dataset side."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import bag_path, drive, write_bag

from seqnet.cli import main as cli_main
from seqnet.data.io import load_dataset

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
pytest.importorskip("utm", reason="utm is not installed (pip install 'seqnet[ros]')")
TOPIC, START, PERIOD = "/camera/image_raw", 10**18, 10**8


def fixes(n: int) -> list[tuple[float, float, int]]:
    return [(63.43 + 1e-4 * j, 10.39, 0) for j in range(n)]  # about 11 m apart, northwards


def test_two_bags_become_a_dataset(tmp_path, capsys):
    ref = write_bag(bag_path(tmp_path, "ros1", "ref"), drive(20, 1), "ros1", fixes=fixes(20), start=START,
                    period=PERIOD, position_offset=PERIOD // 5)  # GPS 20 ms after each image
    qry = write_bag(bag_path(tmp_path, "ros2", "qry"), drive(20, 2, noise=10), "ros2", fixes=fixes(20),
                    start=START + 7 * 10**9, period=PERIOD)
    out = tmp_path / "ds"
    assert cli_main(["-q", "dataset", "from-images", str(ref), str(qry), "--topic", TOPIC, "--positions-topic",
                     "/gps/fix", "--radius", "15", "--method", "pixels", "--out", str(out), "--device", "cpu"]) == 0
    assert "ground truth bag, radius 15 metres" in capsys.readouterr().out
    ds = load_dataset(out)
    assert len(ds.reference) == len(ds.query) == 20 and ds.position_unit == "metres"
    assert ds.reference.names[3] == str(START + 3 * PERIOD) and ds.query.names[0] == str(START + 7 * 10**9)
    np.testing.assert_allclose(ds.reference.positions, ds.query.positions, atol=1e-6)
    assert 10 < ds.reference.positions[1, 1] - ds.reference.positions[0, 1] < 12  # northing grows
    assert ds.extra["topics"] == {"images": TOPIC, "positions": "/gps/fix"}
    assert ds.reference.provenance["id"] == ds.query.provenance["id"]
    assert cli_main(["-q", "eval", "--dataset", str(out), "--methods", "single", "--out", str(tmp_path / "ev"),
                     "--device", "cpu"]) == 0


def test_bag_ground_truth_refusals(tmp_path, capsys):
    ref = write_bag(tmp_path / "ref.bag", drive(4, 1), fixes=fixes(4), period=PERIOD)
    far = write_bag(tmp_path / "far.bag", drive(4, 1), fixes=fixes(2), period=10**9)  # frames 2, 3: 1 s, 2 s off
    odom = write_bag(tmp_path / "odom.bag", drive(4, 1), odometry=[(0.0, float(j)) for j in range(4)])
    base = ["dataset", "from-images", "--topic", TOPIC, "--radius", "15", "--method", "pixels", "--device", "cpu"]
    cases = [([str(ref), str(far), "--positions-topic", "/gps/fix"], "2 of 4 images of the query bag"),
             ([str(ref), str(far), "--positions-topic", "/gps/fix", "--positions-tolerance", "2.5"], None),
             ([str(ref), str(odom), "--positions-topic", "/gps/fix"], "has no topic '/gps/fix'"),
             ([str(ref), str(tmp_path), "--positions-topic", "/gps/fix"], "--topic /camera/image_raw goes with a ROS"),
             ([str(ref), str(ref), "--positions-topic", "/camera/image_raw"], "not a position message")]
    for i, (args, msg) in enumerate(cases):
        rc = cli_main([*base, *args, "--out", str(tmp_path / f"ds{i}")])
        err = capsys.readouterr().err
        assert (rc, msg is None or msg in err) == (0 if msg is None else 2, True), err
