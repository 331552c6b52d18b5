"""``seqnet describe RUN.bag --topic T``: a ROS bag's image topic as an image source (seqnet[ros]).

Bags are written here with rosbags' own writers (conftest.write_bag: ROS 1 .bag, ROS 2 sqlite3 and MCAP bag
directories); describing one must give the very bytes describing the same images as files gives."""

from __future__ import annotations

import io
import json
import sys

import h5py
import numpy as np
import pytest
from conftest import BAG_KINDS, bag_path, mutated, shared_data, write_bag
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError, ImageError, SeqnetError
from seqnet.describe import DescribeConfig, describe_folder
from seqnet.describe.images import list_images, read_any

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
TOPIC = "/camera/image_raw"
START, PERIOD = 1_700_000_000_000_000_000, 100_000_000


def random_images(n: int = 12, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8) for _ in range(n)]


def describe_cli(source, out, *extra) -> np.ndarray:
    assert cli_main(["-q", "describe", str(source), *extra, "--out", str(out), "--device", "cpu"]) == 0
    with h5py.File(out) as h:
        return h["descriptors"][()], [n.decode() for n in h["names"][()]], json.loads(h.attrs["provenance"])


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_a_bag_describes_as_its_images_do_as_files(tmp_path, kind):
    """12 Nordland frames in a bag (rgb8) vs the same PNG files in a list file: byte-identical descriptors."""
    data = shared_data("nordland64") / "summer"
    files = [data / f"images-{i:05d}.png" for i in range(1000, 1120, 10)]
    images = [np.asarray(Image.open(f).convert("RGB")) for f in files]
    bag = write_bag(bag_path(tmp_path, kind), images, kind, start=START, period=PERIOD)
    (tmp_path / "list.txt").write_text("".join(f"{f}\n" for f in files))
    methods = [("pixels", "--patch", "8")] + ([("gem", "--resize", "64x32")] if kind == "ros1" else [])
    for method, *opts in methods:
        args = ["--method", method, *opts]
        got, names, prov = describe_cli(bag, tmp_path / f"{method}-bag.h5", "--topic", TOPIC, *args)
        want, _, want_prov = describe_cli(tmp_path / "list.txt", tmp_path / f"{method}-files.h5", *args)
        assert got.shape == (12, want.shape[1]) and got.tobytes() == want.tobytes()
        assert prov["id"] == want_prov["id"]  # the same describer: comparable by provenance
        assert names == [str(START + i * PERIOD) for i in range(12)]  # the bag timestamps (ns)


def test_the_bag_of_a_ros2_storage_file_is_its_directory(tmp_path):
    bag = write_bag(bag_path(tmp_path, "mcap"), random_images(3), "mcap")
    assert list_images(bag / "run.mcap", TOPIC).names == list_images(bag, TOPIC).names
    (tmp_path / "lone").mkdir()
    (tmp_path / "lone" / "x.mcap").write_bytes((bag / "run.mcap").read_bytes())
    # rosbags reads a storage file alone (rosbag2.Reader picks its plugin by suffix): a lone .mcap is a bag
    assert list_images(tmp_path / "lone" / "x.mcap", TOPIC).names == list_images(bag, TOPIC).names


@pytest.mark.parametrize("encoding", ["bgr8", "mono8", "png", "jpeg"])
def test_encodings_decode_as_their_files(tmp_path, encoding):
    images = random_images(4)
    if encoding == "mono8":
        images = [im[..., 0] for im in images]
    bag = write_bag(tmp_path / "run.bag", images, encoding=encoding)
    frames = list_images(bag, TOPIC).paths
    for im, frame in zip(images, frames, strict=True):
        if encoding == "jpeg":  # lossy: the bag's bytes decode as the same bytes in a file do
            buf = io.BytesIO()
            Image.fromarray(im).save(buf, format="JPEG")
            (tmp_path / "f.jpg").write_bytes(buf.getvalue())
            np.testing.assert_array_equal(read_any(frame), read_any(tmp_path / "f.jpg"))
        else:
            want = np.repeat(im[..., None], 3, axis=2) if encoding == "mono8" else im
            np.testing.assert_array_equal(read_any(frame), want)
        np.testing.assert_array_equal(read_any(frame, grey=True), np.asarray(Image.fromarray(read_any(frame))
                                                                             .convert("L")))


def test_frames_read_out_of_order_and_fitting(tmp_path):
    """Random access (fitting picks evenly spaced frames) reads the frame asked for; a fitted PCA works."""
    images = random_images(10)
    bag = write_bag(tmp_path / "run.bag", images)
    frames = list_images(bag, TOPIC).paths
    for i in (7, 2, 3, 9, 0, 0, 5):
        np.testing.assert_array_equal(read_any(frames[i]), images[i])
    conf = DescribeConfig(method="pixels", patch=0, dim=4)
    desc, names = describe_folder(bag, conf, out=tmp_path / "pca.h5", topic=TOPIC)
    assert desc.shape == (10, 4) and (tmp_path / "pca.pca.npz").exists() and len(set(names)) == 10


def test_errors_name_the_topics_the_type_and_the_encoding(tmp_path, capsys):
    images = random_images(3)
    bag = write_bag(tmp_path / "run.bag", images, fixes=[(63.4, 10.4, 0)] * 3)
    base = ["describe", str(bag), "--method", "pixels", "--out", str(tmp_path / "x.h5")]
    cases = [
        ([], f"is a ROS bag: name its image topic with --topic (its image topics: {TOPIC} (sensor_msgs/msg/Image, "
             "3 messages))"),
        (["--topic", "/nope"], f"has no topic '/nope'; its topics: {TOPIC} (sensor_msgs/msg/Image, 3 messages), "
                               "/gps/fix (sensor_msgs/msg/NavSatFix, 3 messages)"),
        (["--topic", "/gps/fix"], "carries sensor_msgs/msg/NavSatFix, not an image message (sensor_msgs/msg/Image, "
                                  "sensor_msgs/msg/CompressedImage)"),
    ]
    for extra, msg in cases:
        assert cli_main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, err
    odd = write_bag(tmp_path / "odd.bag", [np.zeros((4, 4, 4), np.uint8)], encoding="bgra8")
    with pytest.raises(ImageError, match="image encoding 'bgra8' is not supported; supported: rgb8, bgr8, mono8"):
        read_any(list_images(odd, TOPIC).paths[0])
    assert cli_main(["describe", str(odd), "--topic", TOPIC, "--method", "pixels", "--out",
                     str(tmp_path / "y.h5")]) == 2
    assert "'bgra8' is not supported" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="--topic /cam goes with a ROS bag"):
        list_images(tmp_path, "/cam")


def test_without_rosbags_the_hint_names_the_extra(tmp_path, monkeypatch):
    bag = write_bag(tmp_path / "run.bag", random_images(2))
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(ConfigError, match=r"reading ROS bags needs the package rosbags .*seqnet\[ros\]"):
        list_images(bag, TOPIC)


def test_topic_names_from_a_bag_are_shown_escaped(tmp_path, capsys):
    bag = write_bag(tmp_path / "esc.bag", random_images(2), topic="/cam\x1b]0;owned\x07")
    with pytest.raises(ConfigError) as e:
        list_images(bag)
    assert "\x1b" not in str(e.value) and "/cam\\x1b]0;owned\\x07 (sensor_msgs/msg/Image, 2 messages)" in str(e.value)


def _bag_bytes() -> dict[str, bytes]:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        out = {".bag": write_bag(Path(d) / "a.bag", random_images(3)).read_bytes(),
               "png.bag": write_bag(Path(d) / "p.bag", random_images(3), encoding="png").read_bytes()}
        out[".mcap"] = (write_bag(Path(d) / "m", random_images(3), "mcap") / "m.mcap").read_bytes()
    return out


BAGS = _bag_bytes()


@pytest.mark.filterwarnings("ignore::UserWarning")
@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_bags_give_frames_or_one_error(tmp_path_factory, data):
    """A damaged bag: listing its frames and decoding each gives images or one SeqnetError (messages damaged past
    the index were raw ReaderError / AssertionError / UnicodeDecodeError before)."""
    key = data.draw(st.sampled_from(sorted(BAGS)))
    f = tmp_path_factory.mktemp("bag") / f"x{key[key.index('.'):]}"
    f.write_bytes(data.draw(mutated(BAGS[key], max_flips=6)))
    try:
        frames = list_images(f, TOPIC).paths
    except SeqnetError:
        return
    for frame in frames:
        try:
            assert read_any(frame).dtype == np.uint8
        except SeqnetError:
            pass


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_images_and_their_positions_topic_are_read_in_one_pass(tmp_path, kind, monkeypatch):
    from seqnet.sources.bags import positions as bags
    from seqnet.sources.bags.positions import read_positions

    bag = write_bag(bag_path(tmp_path, kind), random_images(4), kind, odometry=[(j, -j) for j in range(6)],
                    poses=[(2 * j, 1) for j in range(3)], start=START, period=PERIOD, position_offset=PERIOD // 3)
    expected = {t: read_positions(bag, t) for t in ("/odom", "/pose")}
    opened = []
    real = bags.open_bag
    monkeypatch.setattr(bags, "open_bag", lambda path: opened.append(path) or real(path))
    for t, want in expected.items():
        images = list_images(bag, TOPIC, t)
        assert len(opened) == 1 and images.names == [str(START + i * PERIOD) for i in range(4)]
        got = images.positions
        assert got.frame == want.frame and got.stamps.tolist() == want.stamps.tolist()
        assert got.xy.tolist() == want.xy.tolist()
        opened.clear()
    assert list_images(bag, TOPIC).positions is None
    with pytest.raises(ConfigError, match="--positions-topic /odom goes with a ROS bag"):
        list_images(tmp_path / "none", None, "/odom")
