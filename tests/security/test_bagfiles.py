"""The files of a ROS bag checked before rosbags opens any (seqnet.data.bagfiles): FIFOs refused, metadata.yaml
bounded and typed, a bag compressed file by file refused with the command that decompresses it."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from conftest import bag_path, mutated, write_bag
from hypothesis import HealthCheck, given, settings

from seqnet.core.errors import DatasetError, SeqnetError
from seqnet.describe.images import list_images
from seqnet.security.bagfiles import check_bag
from seqnet.sources.bags.positions import read_positions

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
IMAGES = [np.zeros((4, 4, 3), np.uint8) + i for i in range(3)]
TOPIC = "/camera/image_raw"


def within(seconds, fn):
    """``fn()`` in a thread; fails if it has not returned after ``seconds`` (it hung on a FIFO)."""
    out = {}

    def run():
        try:
            out["value"] = fn()
        except Exception as e:  # noqa: BLE001 - handed to the test
            out["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "hung"
    if "error" in out:
        raise out["error"]
    return out.get("value")


@pytest.mark.parametrize("kind", ["ros2", "mcap"])
def test_a_fifo_among_the_storage_files_is_refused_not_opened(tmp_path, kind):
    bag = write_bag(bag_path(tmp_path, kind), IMAGES, kind)
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    storage.rename(storage.with_name("moved" + storage.suffix))
    os.mkfifo(storage)
    with pytest.raises(DatasetError, match=r"bag storage file .* is a FIFO \(named pipe\), not a regular file"):
        within(10, lambda: list_images(bag, TOPIC))
    with pytest.raises(DatasetError, match=r"is a FIFO"):
        within(10, lambda: list_images(storage, TOPIC))  # the storage file names its bag


@pytest.mark.parametrize("name", ["x.bag", "x.db3", "x.mcap"])
def test_a_fifo_bag_file_is_refused_not_opened(tmp_path, name):
    os.mkfifo(tmp_path / name)
    with pytest.raises(DatasetError, match=rf"bag .*{name} is a FIFO"):
        within(10, lambda: read_positions(tmp_path / name, "/gps/fix"))


def test_a_bag_compressed_file_by_file_is_refused_with_the_fix(tmp_path):
    """rosbags would decompress every file whole into a temporary folder (a disk bomb) before reading any."""
    bag = write_bag(bag_path(tmp_path, "mcap"), IMAGES, "mcap")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("compression_mode: ''", "compression_mode: FILE")
                    .replace("compression_format: ''", "compression_format: zstd"))
    with pytest.raises(DatasetError, match=r"is compressed file by file \(zstd\): rosbags would decompress each file "
                                           r"whole .*hint: `ros2 bag decompress BAG`"):
        list_images(bag, TOPIC)


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("version: 9", "version: [9]"), r"version must be an integer in 1\.\.9, got \[9\]"),
    (lambda t: t.replace("nanoseconds: 200000000", "nanoseconds: abc", 1), r"duration.nanoseconds must be an "
                                                                          r"integer"),
    (lambda t: t.replace("  - message_count: 3\n    topic_metadata", "  - message_count: x\n    topic_metadata", 1),
     r"topics_with_message_count\[0\].message_count must be an integer in 0\.\.\d+, got 'x'"),
    (lambda t: t.replace("name: /camera/image_raw", "name: [1, 2]"), r"topic_metadata.name must be text"),
    (lambda t: t.replace("storage_identifier: mcap", "storage_identifier: leveldb"), r"storage_identifier must be "
                                                                                     r"one of sqlite3, mcap"),
    (lambda t: t.replace("  - run.mcap", "  - ../../etc/passwd"), r"'passwd' not found|passwd"),
    (lambda t: t.replace("  - run.mcap", "  - run.mcap\n  - run.mcap"), r"names a storage file twice"),
    (lambda t: "a: &a [x]\n" + "b: " + "[" * 5000 + "]" * 5000, r"not valid YAML|no 'rosbag2_bagfile_information'"),
    (lambda t: "rosbag2_bagfile_information: 3\n", r"no 'rosbag2_bagfile_information' mapping"),
])
def test_metadata_is_typed_before_rosbags_reads_it(tmp_path, edit, match):
    """rosbags stores what metadata.yaml says: a count 'x' failed later in a sum (TypeError), outside its errors."""
    bag = write_bag(bag_path(tmp_path, "mcap"), IMAGES, "mcap")
    meta = bag / "metadata.yaml"
    meta.write_text(edit(meta.read_text()))
    with pytest.raises(DatasetError, match=match):
        check_bag(bag)


def test_storage_files_stay_in_the_bag_folder(tmp_path):
    bag = write_bag(bag_path(tmp_path, "mcap"), IMAGES, "mcap")
    (tmp_path / "elsewhere.mcap").write_bytes((bag / "run.mcap").read_bytes())
    (bag / "run.mcap").unlink()
    (bag / "run.mcap").symlink_to(tmp_path / "elsewhere.mcap")
    with pytest.raises(DatasetError, match=r"'run.mcap' leads outside .* through a symbolic link"):
        check_bag(bag)


@pytest.mark.parametrize("kind", ["ros2", "mcap"])
def test_a_lone_storage_file_is_read_alone(tmp_path, kind):
    """rosbags' rosbag2.Reader opens a .db3 or .mcap by itself (its plugin chosen by suffix): without the
    metadata.yaml of a bag directory beside it, it is read as the storage file it is."""
    bag = write_bag(bag_path(tmp_path, kind), IMAGES, kind, fixes=[(63.4, 10.4, 0)] * 3)
    storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    (tmp_path / "lone").mkdir()
    lone = tmp_path / "lone" / f"x{storage.suffix}"
    lone.write_bytes(storage.read_bytes())
    assert check_bag(lone) == lone and check_bag(storage) == bag
    assert list_images(lone, TOPIC).names == list_images(bag, TOPIC).names
    assert read_positions(lone, "/gps/fix").stamps.tolist() == read_positions(bag, "/gps/fix").stamps.tolist()


def _metadata() -> bytes:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        return (write_bag(Path(d) / "run", IMAGES, "mcap") / "metadata.yaml").read_bytes()


METADATA = _metadata()


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=mutated(METADATA))
def test_fuzzed_metadata_is_checked_or_refused(tmp_path_factory, data):
    bag = tmp_path_factory.mktemp("bag") / "run"
    write_bag(bag, IMAGES, "mcap")
    (bag / "metadata.yaml").write_bytes(data)
    try:
        list_images(bag, TOPIC)
    except SeqnetError:
        pass
