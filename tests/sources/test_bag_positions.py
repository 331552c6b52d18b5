"""Positions from a bag topic (seqnet.sources.bags.positions): NavSatFix to UTM metres, odometry x, y,
nearest-time matching."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import BAG_KINDS, bag_path, mutated, write_bag
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.core.errors import DatasetError
from seqnet.sources.bags.positions import Positions, is_bag, match_positions, read_positions

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
utm = pytest.importorskip("utm", reason="utm is not installed (pip install 'seqnet[ros]')")
START, PERIOD = 10**18, 10**8
IMAGE = [np.zeros((4, 4, 3), np.uint8)]


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_navsatfix_positions_are_utm_metres(tmp_path, kind):
    fixes = [(63.43 + 1e-4 * j, 10.39, 0) for j in range(5)]
    fixes[2] = (63.5, 10.4, -1)  # STATUS_NO_FIX: left out
    bag = write_bag(bag_path(tmp_path, kind), IMAGE, kind, fixes=fixes, start=START, period=PERIOD)
    assert is_bag(bag)
    pos = read_positions(bag, "/gps/fix")
    assert pos.frame == "UTM zone 32V" and pos.stamps.tolist() == [START + j * PERIOD for j in (0, 1, 3, 4)]
    for row, j in zip(pos.xy, (0, 1, 3, 4), strict=True):
        east, north, _, _ = utm.from_latlon(*fixes[j][:2])
        np.testing.assert_allclose(row, [east, north], atol=1e-6)
    assert 10 < np.linalg.norm(pos.xy[1] - pos.xy[0]) < 12  # 1e-4 degrees of latitude: about 11 m


def test_odometry_positions_are_its_x_y(tmp_path):
    bag = write_bag(tmp_path / "run.bag", IMAGE, odometry=[(1.5, -2.0), (3.0, 4.0)])
    pos = read_positions(bag, "/odom")
    assert pos.frame == "odometry frame 'odom'" and pos.xy.tolist() == [[1.5, -2.0], [3.0, 4.0]]


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_posestamped_positions_are_its_x_y(tmp_path, kind):
    bag = write_bag(bag_path(tmp_path, kind), IMAGE, kind, poses=[(1.5, -2.0), (np.nan, 0.0), (3.0, 4.0)],
                    pose_frame="map", start=START, period=PERIOD)
    pos = read_positions(bag, "/pose")
    assert pos.frame == "odometry frame 'map'" and pos.xy.tolist() == [[1.5, -2.0], [3.0, 4.0]]  # NaN: left out
    assert pos.stamps.tolist() == [START, START + 2 * PERIOD]


def test_positions_errors(tmp_path):
    bag = write_bag(tmp_path / "run.bag", IMAGE, fixes=[(0.0, 0.0, -1)] * 2)
    with pytest.raises(DatasetError, match="no usable position \\(no fix in any of its 2 messages\\)"):
        read_positions(bag, "/gps/fix")
    with pytest.raises(DatasetError, match="carries sensor_msgs/msg/Image, not a position message "
                                           "\\(sensor_msgs/msg/NavSatFix, nav_msgs/msg/Odometry"):
        read_positions(bag, "/camera/image_raw")
    with pytest.raises(DatasetError, match="has no topic '/fix'; its topics: /camera/image_raw"):
        read_positions(bag, "/fix")
    with pytest.raises(DatasetError, match="bag not found"):
        read_positions(tmp_path / "none.bag", "/fix")
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    with pytest.raises(DatasetError, match="cannot read the bag .*junk.bag"):
        read_positions(tmp_path / "junk.bag", "/fix")


def test_match_positions_nearest_in_time_within_the_tolerance():
    pos = Positions(np.array([0, 10, 20]) * 10**8, np.array([[0.0, 0], [1, 0], [2, 0]]), "UTM zone 32V")
    stamps = np.array([0, 4, 6, 16, 25]) * 10**8  # seconds 0, 0.4, 0.6, 1.6, 2.5
    np.testing.assert_array_equal(match_positions(stamps, pos, 0.5, "q")[:, 0], [0, 0, 1, 2, 2])
    with pytest.raises(DatasetError, match="4 of 5 images of q have no position message within 0.3 s \\(first: "
                                           "image 1, timestamp 400000000, 0.400 s from the nearest\\)"):
        match_positions(stamps, pos, 0.3, "q")


def _bag_bytes() -> dict[str, bytes]:
    import tempfile
    from pathlib import Path

    fixes = [(63.43 + 1e-4 * j, 10.39, 0) for j in range(4)]
    with tempfile.TemporaryDirectory() as d:
        out = {".bag": write_bag(Path(d) / "a.bag", IMAGE, fixes=fixes).read_bytes()}
        for kind, suffix in (("mcap", ".mcap"), ("ros2", ".db3")):
            out[suffix] = (write_bag(Path(d) / kind, IMAGE, kind, fixes=fixes) / f"{kind}{suffix}").read_bytes()
    return out


BAGS = _bag_bytes()


@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_bags_give_positions_or_one_error(tmp_path_factory, data):
    """A damaged ROS 1 bag, MCAP or sqlite3 file: while it opens and while its messages are read (a chunk or a
    message definition damaged past the index) only positions or one DatasetError come out."""
    suffix = data.draw(st.sampled_from(sorted(BAGS)))
    f = tmp_path_factory.mktemp("bag") / f"x{suffix}"
    f.write_bytes(data.draw(mutated(BAGS[suffix], max_flips=6)))
    try:
        pos = read_positions(f, "/gps/fix")
    except DatasetError:
        return
    assert len(pos.stamps) == len(pos.xy) and np.isfinite(pos.xy).all()
