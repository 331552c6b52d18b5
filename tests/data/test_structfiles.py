"""Reading seqNet .db struct files and converting them (shared struct files, synthetic descriptors)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import mutated, shared_data
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.cli import main
from seqnet.core.errors import DatasetError
from seqnet.data.io import load_dataset
from seqnet.data.structfiles import dataset_from_frame_lists, dataset_from_structs, read_db_struct

NORDLAND_TEST = "nordland_test_d-1_d2-1.db"
NORDLAND_VAL = "nordland_val_d-1_d2-1.db"
MSLS = "msls_amman_d-20_d2-5.db"
OXFORD = "oxford-v1.0_2015-03-17-11-08-44_2014-12-16-18-44-24_test_d-10_d2-5.db"


@pytest.fixture
def structs():
    return shared_data("seqnet_structfiles")


def test_read_nordland(structs):
    s = read_db_struct(structs / NORDLAND_TEST)
    assert s.which_set == "test" and s.frames
    assert len(s.db_names) == len(s.q_names) == 3000
    assert s.utm_db.shape == (3000, 1) and s.utm_db[0, 0] == 15100 and s.utm_db[-1, 0] == 18099
    assert s.db_names[0] == "images-19159.png" and s.pos_dist_thr == 1


def test_read_oxford_and_msls(structs):
    ox = read_db_struct(structs / OXFORD)
    assert ox.utm_db.shape == (1574, 2) and ox.utm_q.shape == (1576, 2) and not ox.frames
    assert ox.pos_dist_thr == 10 and ox.non_triv_pos_dist_sq_thr == 25
    ms = read_db_struct(structs / MSLS)
    assert ms.utm_db.shape == (953, 2) and ms.db_names[0].endswith(".jpg")


def test_nordland_full_frame_list_is_indexed_by_frame(structs, rng):
    full_r = rng.standard_normal((27592, 8)).astype(np.float32)
    full_q = rng.standard_normal((27592, 8)).astype(np.float32)
    ds = dataset_from_structs([read_db_struct(structs / NORDLAND_VAL), read_db_struct(structs / NORDLAND_TEST)],
                              [full_r], [full_q], preset="nordland")
    assert ds.splits == {"val": {"reference": (0, 3000), "query": (0, 3000)},
                         "test": {"reference": (3000, 6000), "query": (3000, 6000)}}
    np.testing.assert_array_equal(ds.reference.descriptors[3000], full_r[15100])
    np.testing.assert_array_equal(ds.query.descriptors[0], full_q[18200])
    assert ds.radius == 1 and ds.position_unit == "frames"
    assert ds.extra["pos_radius"] == 10 and ds.extra["neg_radius"] == 40 and ds.extra["seq_len"] == 10
    assert ds.reference.seq_bounds[2999].tolist() == [0, 3000]
    assert ds.reference.seq_bounds[3000].tolist() == [3000, 6000]


def test_wrong_descriptor_count_is_named(structs, rng):
    s = read_db_struct(structs / MSLS)
    with pytest.raises(DatasetError, match="100 descriptors for 953 struct images"):
        dataset_from_structs([s], [rng.random((100, 4))], [rng.random((835, 4))])
    n = read_db_struct(structs / NORDLAND_TEST)
    with pytest.raises(DatasetError, match="frame indices span 15100..18099"):
        dataset_from_structs([n], [rng.random((5000, 4))], [rng.random((3000, 4))])


def test_msls_cli_with_seq_bounds(structs, tmp_path, rng):
    np.save(tmp_path / "r.npy", rng.random((953, 4), dtype=np.float32))
    np.save(tmp_path / "q.npy", rng.random((835, 4), dtype=np.float32))
    out = tmp_path / "amman"
    rc = main(["dataset", "from-seqnet", "--preset", "msls", "--db", str(structs / MSLS),
               "--ref-desc", str(tmp_path / "r.npy"), "--query-desc", str(tmp_path / "q.npy"),
               "--ref-seq-bounds", str(structs / "msls_amman_database_seqBounds.txt"),
               "--query-seq-bounds", str(structs / "msls_amman_query_seqBounds.txt"), "--out", str(out)])
    assert rc == 0
    ds = load_dataset(out)
    assert ds.radius == 20 and ds.extra["preset"] == "msls" and ds.splits["test"]["query"] == (0, 835)
    assert ds.reference.seq_bounds[:3].tolist() == [[0, 10]] * 3
    assert len(np.unique(ds.query.seq_bounds, axis=0)) == 27
    assert main(["dataset", "check", str(out)]) == 0


def test_oxford_struct_radius_without_preset(structs, tmp_path, rng):
    s = read_db_struct(structs / OXFORD)
    ds = dataset_from_structs([s], [rng.random((1574, 4))], [rng.random((1576, 4))])
    assert ds.radius == 10 and ds.position_unit == "metres" and ds.reference.seq_bounds is None


def test_frame_lists_use_preset_splits(rng):
    r = rng.random((21300, 4), dtype=np.float32)
    ds = dataset_from_frame_lists(r, r, "nordland")
    assert set(ds.splits) == {"train", "val", "test"} and ds.reference.positions[15100, 0] == 15100
    with pytest.raises(Exception, match="positions in metres"):
        dataset_from_frame_lists(r, r, "msls")


def test_not_a_struct_file(tmp_path):
    bad = tmp_path / "x.db"
    bad.write_bytes(b"not a mat file at all" * 20)
    with pytest.raises(DatasetError, match="cannot read .*x.db"):
        read_db_struct(bad)
    with pytest.raises(DatasetError, match="struct file not found"):
        read_db_struct(tmp_path / "missing.db")


def test_struct_missing_field(tmp_path):
    from scipy.io import savemat

    savemat(tmp_path / "s.db", {"dbStruct": {"whichSet": "test", "dbImageFns": np.array(["a"], dtype=object)}},
            format="5")
    with pytest.raises(DatasetError, match="lacks field.*qImageFns"):
        read_db_struct(tmp_path / "s.db")


def struct_file(path, compress=False, **fields):
    """A small seqNet-style ``.db`` (MATLAB v5) with ``fields`` replacing the defaults, written by scipy."""
    from scipy.io import savemat

    base = dict(whichSet="test", dbImageFns=np.array(["a.png", "b.png"], dtype=object),
                qImageFns=np.array(["c.png"], dtype=object), numImages=2.0, numQueries=1.0, posDistThr=10.0,
                posDistSqThr=100.0, nonTrivPosDistSqThr=25.0, utmDb=np.array([[1.0, 2.0], [3.0, 4.0]]),
                utmQ=np.array([[1.0], [3.0]]))
    savemat(path, {"dbStruct": {**base, **fields}}, do_compression=compress)
    return path


def test_small_struct_file_reads(tmp_path):
    for compress in (False, True):
        s = read_db_struct(struct_file(tmp_path / f"s{compress}.db", compress))
        assert s.db_names == ["a.png", "b.png"] and s.q_names == ["c.png"] and s.utm_db.shape == (2, 2)
        assert s.pos_dist_thr == 10 and s.non_triv_pos_dist_sq_thr == 25 and s.which_set == "test"


@pytest.mark.parametrize("fields, match", [
    ({"numImages": np.inf}, r"dbStruct.numImages must be an integer in 0\.\.\d+, got inf"),
    ({"numImages": np.nan}, r"dbStruct.numImages must be an integer in 0\.\.\d+, got nan"),
    ({"numQueries": 1e30}, r"dbStruct.numQueries must be an integer in 0\.\.\d+, got 1e\+30"),
    ({"whichSet": np.zeros((0, 0))}, r"dbStruct.whichSet must be a non-empty string, got float64 of shape \(0, 0\)"),
    ({"whichSet": ""}, r"dbStruct.whichSet must be a non-empty string"),
    ({"whichSet": {"x": 1.0}}, r"dbStruct.whichSet must be a non-empty string, got a struct"),
    ({"dataset": np.zeros((0, 0))}, r"dbStruct.dataset must be a non-empty string"),
    ({"posDistThr": np.zeros((0, 0))}, r"dbStruct.posDistThr must be one number"),
    ({"posDistThr": np.nan}, r"dbStruct.posDistThr must be a number in"),
    ({"utmDb": np.array([[np.nan, 2.0], [3.0, 4.0]])}, r"dbStruct.utmDb holds NaN, inf or values beyond"),
    ({"dbImageFns": np.array([{"x": 1}, {"y": 2}], dtype=object)}, r"dbStruct.dbImageFns\[0\] must be a non-empty "
                                                                    r"string, got a struct"),
    ({"dbImageFns": np.array(["a\n.png", "b"], dtype=object)}, r"dbStruct.dbImageFns\[0\] 'a\\n.png' contains a "
                                                                r"NUL or a line break"),
    ({"qImageFns": np.zeros((0,), dtype=object), "numQueries": 0.0, "utmQ": np.zeros((1, 0))},
     r"dbStruct.numQueries = 0: a struct file of no images"),
])
def test_hostile_struct_fields_are_one_line(tmp_path, fields, match):
    """Inf / NaN counts (OverflowError / ValueError before), an empty whichSet (IndexError before), fields of
    the wrong kind: one DatasetError naming the field."""
    with pytest.raises(DatasetError, match=match):
        read_db_struct(struct_file(tmp_path / "s.db", **fields))


def test_field_names_are_shown_escaped(tmp_path):
    from scipy.io import savemat

    savemat(tmp_path / "s.db", {"dbStruct": {"whichSet": "test", "x\x1b]0;owned\x07": 1.0}})
    with pytest.raises(DatasetError, match=r"lacks field\(s\) dbImageFns.*\(has: whichSet, x\\x1b\]0;owned\\x07\)"):
        read_db_struct(tmp_path / "s.db")


def test_a_decompression_bomb_is_refused_before_it_is_inflated(tmp_path, monkeypatch):
    """A compressed variable inflates block by block within a budget: MAX_RATIO times the file's size, and a
    quarter of the memory there is (here made small, so that a 20 MB variable in a 20 KB file is refused)."""
    from scipy.io import savemat

    from seqnet.security import matfile

    f = struct_file(tmp_path / "s.db", compress=True)
    savemat(tmp_path / "bomb.db", {"dbStruct": {}, "junk": np.zeros((1, 20_000_000), np.uint8)}, do_compression=True)
    assert (tmp_path / "bomb.db").stat().st_size < 50_000
    monkeypatch.setattr(matfile, "MAX_RATIO", 100)
    with pytest.raises(DatasetError, match=r"inflate to more than 100 times the file's size \(a decompression bomb\)"):
        read_db_struct(tmp_path / "bomb.db")
    assert read_db_struct(f).db_names == ["a.png", "b.png"]  # a real one is well within it
    monkeypatch.setattr(matfile, "MAX_RATIO", 1100)
    monkeypatch.setenv("SEQNET_MEMORY_MB", "40")
    with pytest.raises(DatasetError, match=r"a decompression bomb"):
        read_db_struct(tmp_path / "bomb.db")


def mat_file(path, element: bytes):
    """A MATLAB v5 file of one top-level element (little-endian)."""
    path.write_bytes(b"MATLAB 5.0 MAT-file".ljust(116, b" ") + bytes(8) + b"\x00\x01IM" + element)
    return path


def tag(mdtype: int, body: bytes) -> bytes:
    import struct

    return struct.pack("<II", mdtype, len(body)) + body + bytes(-len(body) % 8)


def test_declared_sizes_are_checked_against_the_bytes(tmp_path):
    import struct

    flags = tag(6, struct.pack("<II", 1, 0))  # a cell
    huge = tag(14, flags + tag(5, struct.pack("<ii", 2**31 - 1, 2**31 - 1)) + tag(1, b"dbStruct"))
    with pytest.raises(DatasetError, match=r"declares dimensions \[2147483647, 2147483647\], more elements than"):
        read_db_struct(mat_file(tmp_path / "cell.db", huge))
    long = struct.pack("<II", 14, 2**32 - 1)
    with pytest.raises(DatasetError, match=r"declares 4294967295 bytes, but only 0 follow"):
        read_db_struct(mat_file(tmp_path / "long.db", long))
    good = struct_file(tmp_path / "s.db").read_bytes()
    at = good.index(b"c.png") - 8  # the miUTF8 tag of a name: an unknown type crashed scipy's reader
    with pytest.raises(DatasetError, match=r"is of unknown type 179"):
        read_db_struct(mat_file(tmp_path / "t.db", good[128:at] + b"\xb3" + good[at + 1:]))
    v73 = mat_file(tmp_path / "v73.db", b"")
    v73.write_bytes(v73.read_bytes()[:124] + b"\x00\x02IM")
    with pytest.raises(DatasetError, match=r"it is not version 5 \(a v7.3 file is HDF5"):
        read_db_struct(v73)
    (tmp_path / "v4.db").write_bytes(bytes(200))
    with pytest.raises(DatasetError, match=r"no MATLAB 5.0 header"):
        read_db_struct(tmp_path / "v4.db")


def test_a_crash_of_scipy_ends_the_child_not_this_process(tmp_path, monkeypatch):
    import sys

    from seqnet.security import matlab

    crash = [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"]
    monkeypatch.setattr(matlab, "python_command", lambda *a: crash)
    with pytest.raises(DatasetError, match=r"the reader crashed on it \(signal 11\)"):
        read_db_struct(struct_file(tmp_path / "s.db"))


def test_special_struct_files_are_refused(tmp_path):
    import os

    os.mkfifo(tmp_path / "fifo.db")
    with pytest.raises(DatasetError, match=r"is a FIFO"):
        read_db_struct(tmp_path / "fifo.db")
    with pytest.raises(DatasetError, match=r"struct file not found"):
        read_db_struct(tmp_path / "none.db")


@settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_mat_bytes_are_checked_or_refused(data):
    """The walk over a damaged file's elements: the bytes for scipy, or one DatasetError (fast: no child)."""
    from seqnet.security.matfile import MatChecker

    raw = data.draw(st.sampled_from(FUZZ_SOURCES))
    try:
        MatChecker(data.draw(mutated(raw)), "fuzzed.db").checked()
    except DatasetError:
        pass


@settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_struct_files_read_or_refuse(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("db") / "f.db"
    f.write_bytes(data.draw(mutated(data.draw(st.sampled_from(FUZZ_SOURCES)))))
    try:
        read_db_struct(f)
    except DatasetError:
        pass


def _sources() -> list[bytes]:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        return [struct_file(Path(d) / f"{c}.db", c).read_bytes() for c in (False, True)]


FUZZ_SOURCES = _sources()
