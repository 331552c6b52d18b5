"""Large arrays in bounded memory: streamed memory maps (pages released), take_rows, spill files."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from seqnet.core import memmaps, npy
from seqnet.core.errors import ConfigError, ResourceError
from seqnet.core.memmaps import Spilled, SpillWriter, read_rows, release, streamed, take_rows


@pytest.fixture
def mapped(tmp_path, rng):
    """A ``[500, 24]`` float32 array and its read-only memory map, streamed (resident limit 0)."""
    x = rng.standard_normal((500, 24)).astype(np.float32)
    np.save(tmp_path / "x.npy", x)
    return x, np.load(tmp_path / "x.npy", mmap_mode="r")


def test_streamed_is_decided_by_the_mapping_size(mapped, monkeypatch):
    x, mm = mapped
    assert streamed(mm) and not streamed(x)  # 48 kB over the 0-byte limit; plain arrays never
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "1")
    assert not streamed(mm) and not streamed(mm[10:20])
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "0")
    assert streamed(mm[10:20])  # a view of a streamed map is streamed


@pytest.fixture(autouse=True)
def stream_everything(monkeypatch):
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "0")
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")


@pytest.mark.parametrize("kind", ["sorted", "unsorted", "repeated", "empty", "one"])
def test_take_rows_equals_fancy_indexing(mapped, rng, kind):
    x, mm = mapped
    idx = {"sorted": np.sort(rng.choice(500, 120, replace=False)), "unsorted": rng.choice(500, 120, replace=False),
           "repeated": rng.integers(0, 500, 300), "empty": np.zeros(0, np.int64), "one": np.array([499])}[kind]
    for spill in (False, True):
        got = take_rows(mm, idx, spill=spill)
        np.testing.assert_array_equal(np.asarray(got), x[idx])
        assert isinstance(got, Spilled) == (spill and kind in ("sorted", "one"))  # increasing idx only


def test_take_rows_in_runs_of_several_blocks(mapped, monkeypatch):
    x, mm = mapped
    monkeypatch.setattr(memmaps, "TAKE_BYTES", 10 * 24 * 4)  # runs of 10 rows
    for idx in (np.arange(0, 500, 3)[::-1], np.arange(0, 500, 7)):
        np.testing.assert_array_equal(take_rows(mm, idx), x[idx])
        np.testing.assert_array_equal(np.asarray(take_rows(mm, idx, spill=True)), x[idx])


def test_read_rows_copies_and_releases_without_changing_data(mapped):
    x, mm = mapped
    for a, b in ((0, 7), (100, 400), (490, 600), (3, 3)):
        block = read_rows(mm, a, b)
        np.testing.assert_array_equal(block, x[a:b])
        assert not isinstance(block, np.memmap) and block.flags.writeable
    release(mm[5:9])  # a partial page
    np.testing.assert_array_equal(np.asarray(mm), x)  # faulted in again, unchanged


def resident_file_kb() -> int:
    for line in open("/proc/self/status"):
        if line.startswith("RssFile:"):
            return int(line.split()[1])
    pytest.skip("no RssFile in /proc/self/status")


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc")
def test_released_pages_leave_the_resident_set(tmp_path):
    np.save(tmp_path / "big.npy", np.ones((4096, 4096), np.float32))  # 64 MiB
    mm = np.load(tmp_path / "big.npy", mmap_mode="r")
    before = resident_file_kb()
    total = sum(float(read_rows(mm, a, a + 512).sum()) for a in range(0, 4096, 512))
    streamed_kb = resident_file_kb() - before
    held = float(np.asarray(mm).sum())  # the same pages read without releasing them
    held_kb = resident_file_kb() - before
    assert total == held == 4096 * 4096
    assert streamed_kb < 16 * 1024 and held_kb > 48 * 1024, (streamed_kb, held_kb)


def test_spill_round_trip_leaves_no_file(tmp_path, rng, monkeypatch):
    monkeypatch.setenv("SEQNET_SPILL_DIR", str(tmp_path))
    x = rng.standard_normal((70, 5)).astype(np.float32)
    w = SpillWriter(x.shape, np.float32)
    for a in range(0, 70, 30):
        w.write(x[a : a + 30].astype(np.float64))  # cast to the spill's dtype
    out = w.finish()
    assert isinstance(out, Spilled) and streamed(out) and not out.flags.writeable
    np.testing.assert_array_equal(np.asarray(out), x)
    assert list(tmp_path.iterdir()) == []  # unlinked at once: nothing to clean up, even after a crash


def test_spill_refuses_wrong_blocks_and_short_files(rng):
    w = SpillWriter((10, 4), np.float32)
    with pytest.raises(ValueError, match="does not fit"):
        w.write(np.zeros((3, 5), np.float32))
    w.write(np.zeros((6, 4), np.float32))
    with pytest.raises(ValueError, match="does not fit"):
        w.write(np.zeros((6, 4), np.float32))
    with pytest.raises(ValueError, match="6 of 10 rows"):
        w.finish()
    assert SpillWriter((0, 4), np.float32).finish().shape == (0, 4)


def test_a_spill_without_room_is_an_environment_error(tmp_path, monkeypatch):
    monkeypatch.setenv("SEQNET_SPILL_DIR", str(tmp_path))
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(1 << 30, 1 << 30, 1 << 20))
    with pytest.raises(ResourceError, match="spilled to a temporary file.*MiB free"):
        SpillWriter((100_000, 64), np.float32)


def test_a_spill_folder_that_does_not_exist_is_an_environment_error(tmp_path, monkeypatch):
    monkeypatch.setenv("SEQNET_SPILL_DIR", str(tmp_path / "missing"))
    with pytest.raises(ResourceError, match="SEQNET_SPILL_DIR"):
        SpillWriter((10, 4), np.float32)


def test_limits_from_the_environment(monkeypatch):
    monkeypatch.setenv("SEQNET_SPILL_MB", "1.5")
    assert memmaps.limit("SPILL") == 3 << 19
    monkeypatch.delenv("SEQNET_SPILL_MB")
    assert memmaps.limit("SPILL") == memmaps.SPILL_BYTES
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "lots")
    with pytest.raises(ConfigError, match="SEQNET_RESIDENT_MB must be a number of MiB, got 'lots'"):
        memmaps.limit("RESIDENT")


def test_a_streamed_array_is_saved_in_blocks_as_numpy_saves_it(mapped, tmp_path, monkeypatch):
    x, mm = mapped
    monkeypatch.setattr(memmaps, "TAKE_BYTES", 7 * 24 * 4)  # blocks of 7 rows
    writer = SpillWriter(x.shape, np.float32)
    writer.write(x)
    for arr, name in ((mm, "mapped"), (writer.finish(), "spilled")):
        with open(tmp_path / f"{name}.npy", "wb") as f:
            npy.write_npy(f, arr)
        np.save(tmp_path / "ref.npy", x)
        assert (tmp_path / f"{name}.npy").read_bytes() == (tmp_path / "ref.npy").read_bytes(), name


def test_a_spill_may_finish_short_when_asked(rng):
    x = rng.standard_normal((5, 3)).astype(np.float32)
    writer = SpillWriter((8, 3), np.float32)
    writer.write(x)
    with pytest.raises(ValueError, match="spill holds 5 of 8 rows"):
        writer.finish()
    out = writer.finish(short=True)
    assert isinstance(out, Spilled) and out.shape == (5, 3) and np.array_equal(out, x)
