"""Data model and dataset directory format: round trips, validation errors, splits, atomic saves."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pickle
from pathlib import Path

import h5py
import numpy as np
import pytest

import seqnet.data.io as tv
from seqnet.core.errors import DatasetError, OutputError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.traverse import Dataset, Traverse


def make_dataset(rng, n_ref=12, n_qry=10, dim=4, bounds=True, **kw) -> Dataset:
    def trav(n, name):
        b = None
        if bounds:
            b = np.zeros((n, 2), np.int64)
            b[: n // 2], b[n // 2 :] = (0, n // 2), (n // 2, n)
        return Traverse(rng.standard_normal((n, dim)).astype(np.float32), rng.uniform(0, 100, (n, 2)),
                        names=[f"{name}{i}.png" for i in range(n)], seq_bounds=b, name=name)

    kw.setdefault("splits", {"test": {"reference": (2, 12), "query": (0, 8)},
                             "train": {"reference": (0, 6), "query": (0, 5)}})
    return Dataset(trav(n_ref, "reference"), trav(n_qry, "query"), radius=5.0, name="toy",
                   extra={"pos_radius": 5.0, "source": "test"}, **kw)


@pytest.fixture
def ds(rng):
    return make_dataset(rng)


@pytest.fixture
def ds_dir(tmp_path, ds):
    return save_dataset(ds, tmp_path / "ds")


def assert_traverse_equal(a: Traverse, b: Traverse):
    np.testing.assert_array_equal(np.asarray(a.descriptors), np.asarray(b.descriptors))
    np.testing.assert_array_equal(a.positions, b.positions)
    assert a.names == b.names
    if a.seq_bounds is None:
        assert b.seq_bounds is None
    else:
        np.testing.assert_array_equal(a.seq_bounds, b.seq_bounds)


# ----------------------------------------------------------------------------- round trips


def test_round_trip_npy(ds, ds_dir):
    back = load_dataset(ds_dir)
    assert_traverse_equal(ds.reference, back.reference)
    assert_traverse_equal(ds.query, back.query)
    assert back.radius == 5.0 and back.name == "toy" and back.position_unit == "metres"
    assert back.splits == ds.splits
    assert back.extra == {"pos_radius": 5.0, "source": "test"}
    assert isinstance(back.reference.descriptors, np.memmap)  # memory-mapped by default
    assert not isinstance(load_dataset(ds_dir, mmap=False).reference.descriptors, np.memmap)
    meta = json.loads((ds_dir / "dataset.json").read_text())
    assert meta["format"] == "seqnet-dataset/1"


def test_round_trip_h5_descriptors_and_csv_positions(ds, ds_dir):
    q = ds_dir / "query"
    (q / "descriptors.npy").unlink()
    (q / "positions.npy").unlink()
    (q / "names.txt").unlink()
    with h5py.File(q / "descriptors.h5", "w") as h:
        h["descriptors"] = np.asarray(ds.query.descriptors)
        h["names"] = np.array([n.encode() for n in ds.query.names])
    np.savetxt(q / "positions.csv", ds.query.positions, delimiter=",", fmt="%.17g")
    back = load_dataset(ds_dir)
    assert_traverse_equal(ds.query, back.query)


def test_positions_txt_and_frame_positions(rng, tmp_path):
    t = Traverse(rng.standard_normal((6, 3)).astype(np.float32), np.arange(6.0))
    d = Dataset(t, t, radius=2.0)
    assert d.reference.positions.shape == (6, 1)
    root = save_dataset(d, tmp_path / "f")
    (root / "query" / "positions.npy").unlink()
    (root / "query" / "positions.txt").write_text("\n".join(str(i) for i in range(6)) + "\n")
    back = load_dataset(root)
    assert back.position_unit == "frames"
    np.testing.assert_array_equal(back.query.positions, np.arange(6.0)[:, None])


def test_traverses_key(ds, ds_dir):
    os.rename(ds_dir / "query", ds_dir / "night")
    meta = json.loads((ds_dir / "dataset.json").read_text())
    meta["traverses"] = {"query": "night"}
    (ds_dir / "dataset.json").write_text(json.dumps(meta))
    assert_traverse_equal(ds.query, load_dataset(ds_dir).query)


def test_plain_list_split(ds, ds_dir):
    meta = json.loads((ds_dir / "dataset.json").read_text())
    meta["splits"] = {"val": [1, 9]}
    (ds_dir / "dataset.json").write_text(json.dumps(meta))
    assert load_dataset(ds_dir).splits == {"val": {"reference": (1, 9), "query": (1, 9)}}


# ----------------------------------------------------------------------------- validation errors


def set_meta(root: Path, **changes):
    meta = json.loads((root / "dataset.json").read_text())
    for k, v in changes.items():
        if v is ...:
            meta.pop(k)
        else:
            meta[k] = v
    (root / "dataset.json").write_text(json.dumps(meta))


def expect(root, pattern):
    with pytest.raises(DatasetError, match=pattern) as e:
        load_dataset(root)
    assert "\n" not in str(e.value)
    return str(e.value)


def test_missing_directory(tmp_path):
    expect(tmp_path / "nope", "not found")
    (tmp_path / "file").write_text("x")
    expect(tmp_path / "file", "not a directory")


def test_missing_dataset_json(ds_dir):
    (ds_dir / "dataset.json").unlink()
    expect(ds_dir, "dataset.json is missing")


@pytest.mark.parametrize("text, pattern", [("{not json", "not valid JSON"), ("[1, 2]", "JSON object"),
                                           (b"\xff\xfe\x00garbage", "not UTF-8 text")])
def test_bad_json(ds_dir, text, pattern):
    p = ds_dir / "dataset.json"
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    expect(ds_dir, pattern)


@pytest.mark.parametrize("radius, pattern", [(..., "missing key 'radius'"),
                                             ("far", "radius must be a positive number, got .far."),
                                             (None, "radius must be a positive number"),
                                             (0, "radius must be a positive"), (-3, "radius must be a positive")])
def test_bad_radius(ds_dir, radius, pattern):
    set_meta(ds_dir, radius=radius)
    expect(ds_dir, pattern)


def test_bad_position_unit(ds_dir):
    set_meta(ds_dir, position_unit="furlongs")
    expect(ds_dir, "position_unit")


def test_bad_traverses_key(ds_dir):
    set_meta(ds_dir, traverses=["reference", "query"])
    expect(ds_dir, "'traverses' must be an object")


def test_nan_and_inf_descriptors(ds_dir):
    d = np.load(ds_dir / "query" / "descriptors.npy")
    d[7, 1] = np.nan
    np.save(ds_dir / "query" / "descriptors.npy", d)
    msg = expect(ds_dir, "NaN or inf")
    assert "row 7" in msg and "query" in msg
    assert "(first at row 7, image query7.png): a descriptor that failed; hint: describe that image again" in msg
    d[7, 1] = 0
    d[3, 0] = np.inf
    np.save(ds_dir / "query" / "descriptors.npy", d)
    assert "row 3" in expect(ds_dir, "NaN or inf")


def test_inf_positions(ds_dir):
    p = np.load(ds_dir / "reference" / "positions.npy")
    p[2, 0] = np.inf
    np.save(ds_dir / "reference" / "positions.npy", p)
    expect(ds_dir, "positions contain NaN or inf")


@pytest.mark.parametrize("content, pattern", [
    (b"garbage bytes, not an array", "no NumPy header"),
    (b"", "empty"),
    (b"PK\x03\x04zipzip", "npz archive"),
    (b"\x93NUMPY\x01\x00garbage", "cannot read"),
])
def test_garbage_npy(ds_dir, content, pattern):
    (ds_dir / "query" / "descriptors.npy").write_bytes(content)
    expect(ds_dir, pattern)


def test_truncated_npy(ds_dir):
    f = ds_dir / "query" / "descriptors.npy"
    f.write_bytes(f.read_bytes()[:-20])
    expect(ds_dir, "cannot read")
    with pytest.raises(DatasetError, match="cannot read"):
        load_dataset(ds_dir, mmap=False)


def test_pickled_npy(ds_dir):
    with open(ds_dir / "query" / "descriptors.npy", "wb") as f:
        np.save(f, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    expect(ds_dir, "Python objects")


def test_npz_file_saved_as_npy(ds_dir):
    with open(ds_dir / "query" / "descriptors.npy", "wb") as f:
        np.savez(f, x=np.zeros((3, 3)))
    expect(ds_dir, "npz archive")


@pytest.mark.parametrize("arr, pattern", [(np.zeros(10, np.float32), r"\[N, D\]"),
                                          (np.zeros((0, 4), np.float32), "empty"),
                                          (np.zeros((10, 4), np.int32), "floating point"),
                                          (np.zeros((10, 2, 2), np.float32), r"\[N, D\]")])
def test_bad_descriptor_arrays(ds_dir, arr, pattern):
    np.save(ds_dir / "query" / "descriptors.npy", arr)
    expect(ds_dir, pattern)


def test_count_mismatch(ds_dir):
    np.save(ds_dir / "query" / "positions.npy", np.zeros((9, 2)))
    assert "9 positions for 10 descriptors" in expect(ds_dir, "must be equal")


def test_names_count_mismatch(ds_dir):
    (ds_dir / "query" / "names.txt").write_text("a\nb\n")
    expect(ds_dir, "2 image names for 10")


def test_names_not_utf8(ds_dir):
    (ds_dir / "query" / "names.txt").write_bytes(b"\xff\xfe\xfa\n" * 10)
    expect(ds_dir, "not UTF-8")


def test_dim_mismatch(ds_dir):
    np.save(ds_dir / "query" / "descriptors.npy", np.ones((10, 5), np.float32))
    expect(ds_dir, "dimension mismatch: reference D=4, query D=5")


def test_position_kind_mismatch(ds_dir):
    np.save(ds_dir / "query" / "positions.npy", np.zeros((10, 1)))
    expect(ds_dir, "differ in kind")


@pytest.mark.parametrize("pos, pattern", [(np.zeros((10, 3)), r"\[N, 1\]"), (np.array(["a"] * 10), "must be numbers")])
def test_bad_positions(ds_dir, pos, pattern):
    np.save(ds_dir / "query" / "positions.npy", pos)
    expect(ds_dir, pattern)


@pytest.mark.parametrize("text, pattern", [("", "empty"), ("1,2\nx,y\n", "cannot parse"), ("1,2\n3\n", "cannot parse")])
def test_bad_positions_csv(ds_dir, text, pattern, recwarn):
    (ds_dir / "query" / "positions.npy").unlink()
    (ds_dir / "query" / "positions.csv").write_text(text)
    expect(ds_dir, pattern)
    assert not [w for w in recwarn if "loadtxt" in str(w.message)]  # no stray warning on stderr


def test_missing_files(ds_dir):
    (ds_dir / "query" / "positions.npy").unlink()
    expect(ds_dir, "no positions file")
    (ds_dir / "reference" / "descriptors.npy").unlink()
    expect(ds_dir, "no descriptor file")
    os.rename(ds_dir / "reference", ds_dir / "ref")
    expect(ds_dir, "reference traverse directory not found")


@pytest.mark.parametrize("bounds, pattern", [
    (np.zeros((10, 3), np.int64), r"must be \[10, 2\]"),
    (np.tile([[0, 5]], (10, 1)), r"seq_bounds\[5\] = \[0, 5\] does not contain image 5"),
    (np.tile([[0, 11]], (10, 1)), "does not contain"),
    (np.tile([[0.0, 10.0]], (10, 1)), "integers"),
])
def test_bad_seq_bounds(ds_dir, bounds, pattern):
    np.save(ds_dir / "query" / "seq_bounds.npy", bounds)
    expect(ds_dir, pattern)


@pytest.mark.parametrize("splits, pattern", [
    ({"test": [0, 11]}, "outside 0:10"),
    ({"test": [5, 5]}, "or empty"),
    ({"test": {"reference": [0, 5]}}, "split 'test' must be"),
    ({"test": "all"}, "split 'test' must be"),
    ({"test": [1]}, "split 'test' must be"),
    ([0, 5], "'splits' must be an object"),
])
def test_bad_splits(ds_dir, splits, pattern):
    set_meta(ds_dir, splits=splits)
    expect(ds_dir, pattern)


def test_bad_h5(ds, ds_dir):
    q = ds_dir / "query"
    (q / "descriptors.npy").unlink()
    (q / "descriptors.h5").write_bytes(b"not hdf5 at all")
    expect(ds_dir, "cannot read .* as HDF5")
    (q / "descriptors.h5").unlink()
    with h5py.File(q / "descriptors.h5", "w") as h:
        h["features"] = np.zeros((10, 4), np.float32)
        h["other"] = np.zeros((10, 4), np.float32)
        h.create_group("descriptors_group")
    expect(ds_dir, "no dataset 'descriptors' .found: features, other")
    (q / "descriptors.h5").unlink()
    with h5py.File(q / "descriptors.h5", "w") as h:  # one float dataset of another name is not taken either
        h["positions"] = np.zeros((10, 2), np.float32)
    expect(ds_dir, "no dataset 'descriptors' .found: positions.; seqnet does not guess")


def test_traverse_constructor_errors(rng):
    with pytest.raises(DatasetError, match="must be numbers"):
        Traverse(np.zeros((3, 2), np.float32), np.array([["a", "b"]] * 3))
    t = Traverse([[1.0, 2.0]], [[0.0]])  # array-likes are converted
    assert t.descriptors.shape == (1, 2) and len(t) == 1 and t.dim == 2
    with pytest.raises(DatasetError, match="integers"):
        Traverse(np.zeros((2, 2), np.float32), np.zeros(2), seq_bounds=np.array([[0.5, 2.0]] * 2))


@pytest.mark.parametrize("p", [2, 1])
def test_transposed_positions_say_transpose(rng, p):
    """Positions given as [2, N] were refused without the hint recall_at_k gives (pos.T)."""
    d = rng.standard_normal((40, 8)).astype(np.float32)
    with pytest.raises(DatasetError, match=rf"got shape \({p}, 40\); they look transposed .*pass positions\.T "
                                           rf"\(\[40, {p}\]"):
        Traverse(d, rng.random((p, 40)))
    with pytest.raises(DatasetError, match=r"got shape \(3, 40\)$"):  # 3 coordinates: no transpose would do
        Traverse(d, rng.random((3, 40)))
    assert Traverse(d, rng.random((2, 40)).T).positions.shape == (40, 2)


def test_repr_is_one_short_line(rng):
    """The dataclass repr printed every name and array: 31,702 characters for 1000 frames."""
    names = [f"img{i:05d}.jpg" for i in range(1000)]
    t = Traverse(rng.random((1000, 64), dtype=np.float32), np.arange(1000), names=names, name="query")
    assert repr(t) == "Traverse('query': 1000 images, D=64 float32, frame numbers, names)"
    u = Traverse(np.ones((3, 2), np.float32), np.ones((3, 2)), seq_bounds=np.array([[0, 3]] * 3))
    assert repr(u) == "Traverse('traverse': 3 images, D=2 float32, positions [3, 2], seq_bounds)"


# ----------------------------------------------------------------------------- subset and split


def test_subset_clips_bounds(ds):
    sub = ds.reference.subset(3, 9)
    assert len(sub) == 6
    np.testing.assert_array_equal(sub.descriptors, ds.reference.descriptors[3:9])
    # original sequences [0, 6) and [6, 12) clipped to [3, 9) and shifted
    np.testing.assert_array_equal(sub.seq_bounds, [[0, 3]] * 3 + [[3, 6]] * 3)
    assert sub.names == ds.reference.names[3:9]


@pytest.mark.parametrize("rng_", [(-1, 3), (3, 3), (5, 2), (0, 13)])
def test_subset_bad_range(ds, rng_):
    with pytest.raises(DatasetError, match="half-open"):
        ds.reference.subset(*rng_)


def test_dataset_split(ds):
    test = ds.split("test")
    assert len(test.reference) == 10 and len(test.query) == 8 and test.splits == {} and test.name == "toy[test]"
    assert ds.split("all") is ds and ds.split(None) is ds
    with pytest.raises(DatasetError, match="no split 'val'; valid: all, test, train"):
        ds.split("val")


def test_dataset_constructor_validation(rng):
    with pytest.raises(DatasetError, match="outside"):
        make_dataset(rng, splits={"test": {"reference": (0, 5), "query": (0, 50)}})
    with pytest.raises(DatasetError, match="no query range"):
        make_dataset(rng, splits={"test": {"reference": (0, 5)}})
    good = make_dataset(rng)
    with pytest.raises(DatasetError, match="radius"):
        Dataset(good.reference, good.query, radius=float("nan"))


# ----------------------------------------------------------------------------- saving


def test_save_refuses_non_empty_and_overwrites(ds, ds_dir, rng):
    with pytest.raises(OutputError, match="not empty"):
        save_dataset(ds, ds_dir)
    other = make_dataset(rng, n_ref=7, n_qry=6, bounds=False, splits={})
    save_dataset(other, ds_dir, overwrite=True)
    back = load_dataset(ds_dir)
    assert len(back.reference) == 7 and back.query.seq_bounds is None
    assert not (ds_dir / "query" / "seq_bounds.npy").exists()
    assert sorted(p.name for p in ds_dir.parent.iterdir()) == ["ds"]  # no temporary, backup or lock left


def test_save_into_empty_existing_dir(ds, tmp_path):
    (tmp_path / "empty").mkdir()
    save_dataset(ds, tmp_path / "empty")
    assert load_dataset(tmp_path / "empty").name == "toy"


def test_save_onto_file_is_an_error(ds, tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="not a directory"):
        save_dataset(ds, tmp_path / "f", overwrite=True)
    assert (tmp_path / "f").read_text() == "x"


def test_save_is_atomic_on_failure(ds, tmp_path, rng, monkeypatch):
    root = save_dataset(ds, tmp_path / "ds")
    before = {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()}
    calls = []

    def failing(t, path):
        calls.append(path)
        if len(calls) == 2:
            raise OSError("disk full")
        return original(t, path)

    original = tv.save_traverse
    monkeypatch.setattr(tv, "save_traverse", failing)
    with pytest.raises(OSError, match="disk full"):
        save_dataset(make_dataset(rng, n_ref=5, n_qry=5, splits={}), root, overwrite=True)
    after = {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()}
    assert after == before  # the old dataset is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # and no temporary directory is left
    with pytest.raises(OSError, match="disk full"):
        calls.clear()
        save_dataset(ds, tmp_path / "new")
    assert not (tmp_path / "new").exists()


def test_save_writes_float32_and_keeps_extra(rng, tmp_path):
    t = Traverse(rng.standard_normal((4, 3)), np.arange(4.0))  # float64 descriptors
    d = Dataset(t, t, radius=1.0, extra={"preset": "x", "radius": 99})  # core keys are not overridden by extra
    root = save_dataset(d, tmp_path / "d")
    assert np.load(root / "query" / "descriptors.npy").dtype == np.float32
    assert json.loads((root / "dataset.json").read_text())["radius"] == 1.0
    assert load_dataset(root).extra == {"preset": "x"}


def test_pickle_free_loading(ds_dir):
    # names and positions never go through pickle; sanity check of the test helper itself
    assert pickle.loads(pickle.dumps(1)) == 1
    assert load_dataset(ds_dir).query.names[0] == "query0.png"


def test_saved_files_get_normal_permissions(ds, tmp_path):
    root = save_dataset(ds, tmp_path / "perm")
    mask = os.umask(0o022)
    os.umask(mask)
    assert (root.stat().st_mode & 0o777) == 0o777 & ~mask  # not mkdtemp's 0700
    for f in (root / "dataset.json", root / "query" / "descriptors.npy", root / "query" / "positions.npy"):
        assert (f.stat().st_mode & 0o777) == 0o666 & ~mask, f  # not mkstemp's 0600


def test_names_with_line_breaks_rejected(rng, tmp_path):
    t = Traverse(rng.standard_normal((2, 3)).astype(np.float32), np.arange(2.0), names=["a.png", "b\n.png"])
    with pytest.raises(DatasetError, match="line separator"):
        save_dataset(Dataset(t, t, radius=1.0), tmp_path / "n")
    assert list(tmp_path.iterdir()) == []


def test_a_subset_is_not_scanned_again(monkeypatch):
    """Traverse.subset of a checked traverse does not re-scan its descriptors (only the constructor checks)."""
    import seqnet.data.traverse as tr

    t = tr.Traverse(np.ones((10, 3), np.float32), np.arange(10.0), seq_bounds=np.array([[0, 4]] * 4 + [[4, 10]] * 6))
    calls = []
    monkeypatch.setattr(tr, "validate_traverse", lambda x: calls.append(x))
    part = t.subset(2, 8)
    assert calls == [] and len(part) == 6 and part.seq_bounds.tolist()[0] == [0, 2]
    assert part.descriptors.base is not None  # a view, not a copy


def test_datasets_carry_checksums_checked_on_open_and_by_check(ds, tmp_path, capsys, caplog):
    """A seqnet-written dataset records its files' hashes. Changed by hand (the directory format allows
    it), it still opens after every content check, with a warning naming the file (logged at default
    verbosity, once per process even when a command opens it twice); `seqnet dataset check` hashes every byte
    and refuses it."""
    from seqnet.cli import main as cli_main

    root = save_dataset(ds, tmp_path / "d")
    assert "query/descriptors.npy" in json.loads((root / "dataset.json").read_text())["checksums"]
    assert cli_main(["dataset", "check", str(root)]) == 0
    desc = np.load(root / "query" / "descriptors.npy")
    np.save(root / "query" / "descriptors.npy", desc[:, ::-1].copy())  # valid, but not what seqnet wrote
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        load_dataset(root)
        load_dataset(root)
    said = [r.getMessage() for r in caplog.records if "changed since seqnet wrote the dataset" in r.getMessage()]
    assert len(said) == 1 and "query/descriptors.npy" in said[0] and said[0].startswith(str(root)), said
    capsys.readouterr()
    assert cli_main(["dataset", "check", str(root)]) == 2
    assert "query/descriptors.npy changed since seqnet wrote the dataset" in capsys.readouterr().err


def test_a_range_in_place_of_a_split_name_needs_no_new_dataset(synth_dataset):
    ds = synth_dataset
    q = ds.split("10:30")
    assert (len(q.reference), len(q.query)) == (len(ds.reference), 20) and q.name.endswith("[10:30]")
    r = ds.split("0:50,10:30")
    assert (len(r.reference), len(r.query)) == (50, 20)
    np.testing.assert_array_equal(r.query.descriptors, ds.query.descriptors[10:30])
    for bad, msg in (("10:5000", "outside"), ("x", "or a range A:B"), ("5:2", "outside")):
        with pytest.raises(DatasetError, match=msg):
            ds.split(bad)


def test_a_copied_dataset_is_named_after_its_folder(ds, tmp_path):
    """A dataset named after the folder seqnet wrote it into, copied (``cp -r``) or renamed, is named after the
    folder it is in now; a name given apart from the folder (``--name``) stays."""
    import shutil

    root = save_dataset(dataclasses.replace(ds, name="orig"), tmp_path / "orig")
    assert json.loads((root / "dataset.json").read_text())["folder"] == "orig"
    assert load_dataset(root).name == "orig"
    shutil.copytree(root, tmp_path / "copy")
    assert load_dataset(tmp_path / "copy").name == "copy"
    assert load_dataset(tmp_path / "copy").split("0:3").name == "copy[0:3]"
    named = save_dataset(ds, tmp_path / "d2")  # named "toy", written into d2
    shutil.copytree(named, tmp_path / "d3")
    assert load_dataset(tmp_path / "d3").name == "toy"


def test_a_copied_dataset_written_before_folders_were_recorded_is_named_by_both(ds, tmp_path):
    """A dataset seqnet wrote before dataset.json recorded its folder (checksums, no ``folder``), copied: both
    names (``copy (written as orig)``); a hand-written dataset.json (no checksums) keeps its name."""
    import shutil

    root = save_dataset(dataclasses.replace(ds, name="orig"), tmp_path / "orig")
    meta = json.loads((root / "dataset.json").read_text())
    del meta["folder"]
    (root / "dataset.json").write_text(json.dumps(meta))
    assert load_dataset(root).name == "orig"
    shutil.copytree(root, tmp_path / "copy")
    assert load_dataset(tmp_path / "copy").name == "copy (written as orig)"
    del meta["checksums"]
    (tmp_path / "copy" / "dataset.json").write_text(json.dumps(meta))
    assert load_dataset(tmp_path / "copy").name == "orig"


def _unit_rows(n=30, d=8, seed=0):
    x = np.random.default_rng(seed).standard_normal((n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_api_built_traverses_name_their_side_and_transposed_descriptors():
    """Both sides were 'traverse'; [D, N] descriptors got '30 positions for 8 descriptors' without a hint."""
    from seqnet.data.traverse import Dataset, Traverse

    q, fr = _unit_rows(), np.arange(30.0)
    bad = q.copy()
    bad[3] = np.nan
    with pytest.raises(DatasetError, match=r"name='query' or 'reference'\) names it\): descriptors contain NaN"):
        Traverse(bad, fr)
    with pytest.raises(DatasetError, match=r"descriptors look transposed \(\[D, N\] = \[8, 30\]\): pass descriptors.T"):
        Traverse(q.T, fr)
    ds = Dataset(reference=Traverse(q, fr), query=Traverse(q, fr), radius=1.0)
    assert (ds.reference.name, ds.query.name) == ("reference", "query")


def test_dataset_repr_is_short():
    """repr(Dataset) printed the whole memory map (30 KB)."""
    from seqnet.data.traverse import Dataset, Traverse

    q, fr = _unit_rows(3000, 64), np.arange(3000.0)
    ds = Dataset(reference=Traverse(q, fr), query=Traverse(q, fr), radius=2.0, name="x",
                 splits={"test": {"query": (0, 9)}})
    assert repr(ds) == ("Dataset('x': 3000 reference x 3000 query images, D=64, radius 2 frames, splits test=0:9)")


def test_positives_as_lists_or_bool_matrix(caplog):
    """Lists and bool matrices were refused ('positives must be a Positives, got list') with no hint."""
    import logging

    from seqnet.data.positives import Positives
    from seqnet.data.traverse import Dataset, Traverse

    q, fr = _unit_rows(), np.arange(30.0)
    lists = [[j for j in (i - 1, i, i + 1) if 0 <= j < 30] for i in range(30)]
    grid = np.zeros((30, 30), bool)
    for i, row in enumerate(lists):
        grid[i, row] = True
    want = Positives.from_lists(lists)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        for given in (lists, grid, want):
            ds = Dataset(reference=Traverse(q, fr), query=Traverse(q, fr), radius=1.0, positives=given)
            assert np.array_equal(ds.positives.indices, want.indices)
    assert not caplog.records  # symmetric positives read alike both ways: nothing to say
    with pytest.raises(DatasetError, match=r"transposed\? the matrix is \[30, 20\]"):
        Dataset(reference=Traverse(q, fr), query=Traverse(q[:20], fr[:20]), radius=1.0, positives=grid[:20].T)
    with pytest.raises(DatasetError, match=r"Positives.from_lists"):
        Dataset(reference=Traverse(q, fr), query=Traverse(q, fr), radius=1.0, positives="gt.json")


def test_all_zero_rows_name_their_images():
    """A blank image was refused by row number only."""
    from seqnet.data.traverse import Traverse

    q = _unit_rows()
    q[[4, 5]] = 0
    names = [f"images-{i:05d}.png" for i in range(30)]
    with pytest.raises(DatasetError, match=r"query: descriptors: row 4 \(image images-00004.png\) is all zeros \(2 "
                                           r"such images.*images-00004.png, images-00005.png\).*same name from both"):
        Traverse(q, np.arange(30.0), names=names, name="query")


def test_dataset_names_its_sides_without_renaming_the_callers_traverses():
    """Dataset() renamed the caller's unnamed traverses in place: a self-matching query was called 'reference'."""
    from seqnet.data.traverse import Dataset, Traverse

    q, fr = _unit_rows(), np.arange(30.0)
    t = Traverse(q, fr)
    ds = Dataset(reference=t, query=t, radius=1.0)
    assert (t.name, ds.reference.name, ds.query.name) == ("traverse", "reference", "query")
    assert ds.query.descriptors is t.descriptors  # a shallow copy: no array is copied
    again = Dataset(reference=Traverse(q, fr), query=t, radius=1.0)
    assert again.query.name == "query"
    named = Traverse(q, fr, name="winter")
    assert Dataset(reference=named, query=named, radius=1.0).query is named  # a named traverse is kept as given


@pytest.mark.parametrize("unit, hint", [("meters", '"metres"'), ("m", '"metres"'), ("Frame", '"frames"'),
                                        ("furlongs", None)])
def test_a_unit_spelt_another_way_is_named(unit, hint):
    """A hand-written dataset.json with "meters" or "m" was refused without saying what to write."""
    pos = np.arange(4, dtype=float)[:, None]
    x = np.eye(4, 3, dtype=np.float32) + 0.5
    with pytest.raises(DatasetError) as e:
        Dataset(Traverse(x, pos), Traverse(x.copy(), pos.copy()), 1.0, position_unit=unit)
    assert str(e.value).startswith(f"position_unit {unit!r} is not one of ('frames', 'metres')")
    assert (f"(hint: {hint}" in str(e.value)) if hint else "hint" not in str(e.value)
