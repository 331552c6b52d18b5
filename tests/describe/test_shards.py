"""Sharded describing (``--shard k/N``, torchrun's RANK/WORLD_SIZE) and ``seqnet describe merge``: the merge
equals one unsharded run, and every inconsistent set of shards is refused with one line."""

from __future__ import annotations

import json

import h5py
import pytest
from conftest import image_folder
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError, DatasetError
from seqnet.core.provenance import ProvenanceError, sidecar
from seqnet.describe import DescribeConfig, Shard, main, merge_shards, parse_shard
from seqnet.describe.shards import env_shard, resolve_shard


def describe(*args):
    return cli_main(["-q", "describe", *map(str, args), "--device", "cpu"])


def h5(path):
    with h5py.File(path) as h:
        return h["descriptors"][()], list(h["names"][()]), h.attrs["config"], json.loads(h.attrs["provenance"])


@pytest.fixture
def big_folder(tmp_path):
    """23 random 32×16 PNG images (batches of 4 leave a short last one)."""
    return image_folder(tmp_path / "many", 23, seed=1, stem="img")


@pytest.mark.parametrize("opts", [["--method", "pixels"], ["--method", "pixels", "--dim", "6"]])
def test_sharded_then_merged_equals_one_run_h5(big_folder, tmp_path, opts):
    common = [*opts, "--batch-size", "4"]
    assert describe(big_folder, *common, "--out", tmp_path / "full.h5") == 0
    for k in (2, 0, 1):
        assert describe(big_folder, *common, "--shard", f"{k}/3", "--out", tmp_path / f"s{k}.h5") == 0
    shards = [tmp_path / f"s{k}.h5" for k in (1, 2, 0)]  # any order
    assert describe("merge", *shards, "--out", tmp_path / "m.h5") == 0
    full, merged = h5(tmp_path / "full.h5"), h5(tmp_path / "m.h5")
    assert full[0].tobytes() == merged[0].tobytes() and full[1:] == merged[1:]
    rec = h5(tmp_path / "s1.h5")[3]["shard"]
    assert rec["index"] == 1 and rec["count"] == 3 and rec["frames"] == [8, 16] and rec["images"] == 23
    assert {k: v for k, v in h5(tmp_path / "s1.h5")[3].items() if k != "shard"} == full[3]


def test_npy_shards_merge_like_one_npy_run(big_folder, tmp_path):
    conf = DescribeConfig(batch_size=4)
    main(conf, big_folder, tmp_path / "full.npy")
    for k in range(2):
        main(conf, big_folder, tmp_path / f"s{k}.npy", shard=Shard(k, 2))
    merge_shards([tmp_path / "s1.npy", tmp_path / "s0.npy"], tmp_path / "m.npy")
    assert (tmp_path / "full.npy").read_bytes() == (tmp_path / "m.npy").read_bytes()
    for f in (sidecar, lambda p: p.with_name(p.stem + ".names.txt")):
        assert f(tmp_path / "full.npy").read_text() == f(tmp_path / "m.npy").read_text()
    with pytest.raises(ConfigError, match=r"must end\s+in .npy"):
        merge_shards([tmp_path / "s0.npy", tmp_path / "s1.npy"], tmp_path / "m.h5")


@pytest.fixture
def shards(big_folder, tmp_path):
    """Shards 0/3, 1/3, 2/3 of ``big_folder`` (pixels, batches of 4)."""
    out = [tmp_path / f"s{k}.h5" for k in range(3)]
    for k, o in enumerate(out):
        main(DescribeConfig(batch_size=4), big_folder, o, shard=Shard(k, 3))
    return out


def test_merge_refuses_incomplete_or_inconsistent_shards(shards, big_folder, tmp_path, capsys):
    s0, s1, s2 = shards
    with pytest.raises(ConfigError, match=r"shard\(s\) 2/3 missing"):
        merge_shards([s0, s1], tmp_path / "m.h5")
    with pytest.raises(ConfigError, match="shard 1/3 is given twice"):
        merge_shards([s0, s1, s1, s2], tmp_path / "m.h5")
    other = tmp_path / "other.h5"
    main(DescribeConfig(batch_size=4, patch=4), big_folder, other, shard=Shard(2, 3))
    with pytest.raises(ProvenanceError, match="made differently: patch: 4 vs 8"):
        merge_shards([s0, s1, other], tmp_path / "m.h5")
    four = tmp_path / "four.h5"
    main(DescribeConfig(batch_size=4), big_folder, four, shard=Shard(3, 4))
    with pytest.raises(ConfigError, match="has count 4 but"):
        merge_shards([s0, s1, s2, four], tmp_path / "m.h5")
    main(DescribeConfig(), big_folder, tmp_path / "whole.h5")
    with pytest.raises(ConfigError, match="is not a shard output"):
        merge_shards([tmp_path / "whole.h5", s1], tmp_path / "m.h5")
    with pytest.raises(ConfigError, match="is one of the shards"):
        merge_shards([s0, s1, s2], s0)
    assert not (tmp_path / "m.h5").exists()
    assert describe("merge", s0, s1, "--out", tmp_path / "m.h5") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "2/3 missing" in err


def test_merge_refuses_shards_of_another_image_list(shards, big_folder, tmp_path):
    (big_folder / "img9.png").rename(big_folder / "zz.png")  # same count, another list
    moved = tmp_path / "moved.h5"
    main(DescribeConfig(batch_size=4), big_folder, moved, shard=Shard(2, 3))
    with pytest.raises(ConfigError, match="has list_sha1"):
        merge_shards([shards[0], shards[1], moved], tmp_path / "m.h5")


@pytest.mark.parametrize("bad, msg", [("3/3", r"k in 0\.\.2"), ("1/0", "N >= 1"), ("a/b", "must be k/N"),
                                      ("1/2/3", "must be k/N"), ("0/8", "is empty")])
def test_bad_shard_is_one_line_exit_2(big_folder, tmp_path, capsys, bad, msg):
    assert describe(big_folder, "--method", "pixels", "--batch-size", "4", "--shard", bad,
                    "--out", tmp_path / "x.h5") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and pytest.importorskip("re").search(msg, err), err
    assert not (tmp_path / "x.h5").exists()


def test_torchrun_rank_picks_the_shard(monkeypatch, big_folder, tmp_path):
    monkeypatch.setenv("WORLD_SIZE", "3")
    monkeypatch.setenv("RANK", "1")
    assert env_shard() == Shard(1, 3) and resolve_shard(None) == Shard(1, 3)
    assert resolve_shard("2/3") == Shard(2, 3)  # --shard wins
    assert describe(big_folder, "--method", "pixels", "--batch-size", "4", "--out", tmp_path / "r.h5") == 0
    assert h5(tmp_path / "r.shard-1-of-3.h5")[3]["shard"]["index"] == 1 and not (tmp_path / "r.h5").exists()
    monkeypatch.setenv("RANK", "x")
    with pytest.raises(ConfigError, match="RANK='x'"):
        env_shard()
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert env_shard() is None and resolve_shard("0/1") is None and parse_shard(" 1 / 2 ") == Shard(1, 2)


def test_shard_ranges_tile_the_list_on_batch_boundaries():
    for n, count, batch in ((23, 3, 4), (100, 7, 8), (5, 5, 1), (9, 2, 8)):
        ranges = [Shard(k, count).frames(n, batch) for k in range(count)]
        assert ranges[0][0] == 0 and ranges[-1][1] == n
        assert all(a[1] == b[0] and a[1] % batch == 0 for a, b in zip(ranges, ranges[1:], strict=False))


@pytest.fixture
def npy_shards(big_folder, tmp_path):
    """Shards 0/2 and 1/2 of ``big_folder`` as ``.npy`` outputs (their records in JSON sidecars)."""
    out = [tmp_path / f"n{k}.npy" for k in range(2)]
    for k, o in enumerate(out):
        main(DescribeConfig(batch_size=4), big_folder, o, shard=Shard(k, 2))
    return out


def edit_record(path, **fields):
    """Change fields of the shard record in ``path``'s provenance sidecar (as a hostile file would)."""
    record = json.loads(sidecar(path).read_text())
    record["shard"].update(fields)
    sidecar(path).write_text(json.dumps(record))


@pytest.mark.parametrize("fields, msg", [
    ({"count": 10**12}, r"shard\(s\) 2/1000000000000, 3/1000000000000, .*, \.\.\. missing"),
    ({"count": "x"}, r"'shard' record's count must be an integer in 1\.\.\d+, got 'x'"),
    ({"index": [0]}, r"'shard' record's index must be an integer in 0\.\.1, got \[0\]"),
    ({"frames": [1, 2, 3]}, r"'shard' record's frames must be \[first, end\], got \[1, 2, 3\]"),
    ({"frames": [8, 4]}, r"frames\[1\] must be an integer in 9\.\.23, got 4"),
    ({"images": 2.5}, r"images must be an integer in 1\.\.\d+, got 2\.5"),
    ({"batch_size": None}, r"batch_size must be an integer"),
    ({"list_sha1": {"a": 1}}, r"list_sha1 must be a hexadecimal hash"),
])
def test_merge_checks_every_field_of_a_shard_record(npy_shards, tmp_path, capsys, fields, msg):
    """The shard record is read from a file: a count of 10**12 must not loop over range(count), and a field of
    the wrong type is one line naming it, never a raw TypeError."""
    edit_record(npy_shards[0], **fields)
    if "count" in fields:  # both shards agree on the count, so it is the count that is checked
        edit_record(npy_shards[1], **fields)
    with pytest.raises((ConfigError, DatasetError), match=msg):
        merge_shards(npy_shards, tmp_path / "m.npy")
    assert describe("merge", *npy_shards, "--out", tmp_path / "m.npy") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "internal error" not in err


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner,
                                                                                        max_size=3), max_leaves=8)
RECORD = {"index": 0, "count": 2, "frames": [0, 12], "images": 23, "batch_size": 4, "list_sha1": "0123abcd"}


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_fuzzed_shard_records_are_checked_or_refused(data):
    from pathlib import Path

    from seqnet.describe.merge import shard_record

    record = dict(RECORD)
    for key in data.draw(st.lists(st.sampled_from([*RECORD, "extra"]), min_size=1, max_size=3)):
        record[key] = data.draw(JSON_VALUES)
    try:
        out = shard_record(record, Path("s.npy"))
    except DatasetError:
        return
    assert 0 <= out["index"] < out["count"] and 0 <= out["frames"][0] < out["frames"][1] <= out["images"]
