"""MSLS city folders (postprocessed.csv + seq_info.csv + images/) → a dataset (`seqnet dataset from-msls`)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from conftest import mutated
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.cli import main
from seqnet.core.errors import ConfigError, DatasetError
from seqnet.data.io import load_dataset
from seqnet.data.msls import dataset_from_msls, expand_cities, read_msls_side

POST = ",key,easting,northing,unique_cluster,control_panel,night,view_direction"  # mapillary_sls's headers
SEQ = ",key,sequence_key,frame_number"
RAW = ",key,lon,lat,ca,captured_at,pano"


def write_side(folder, keys, east, seqs, frames, images=True):
    """One MSLS database/query folder, files as MSLS ships them (pandas index as the first, unnamed column)."""
    folder.mkdir(parents=True)
    rows = [f"{i},{k},{e:.2f},5813000.00,{i // 3},False,False,Forward"
            for i, (k, e) in enumerate(zip(keys, east, strict=True))]
    (folder / "postprocessed.csv").write_text(POST + "\n" + "\n".join(rows) + "\n")
    rows = [f"{i},{k},{s},{f}" for i, (k, s, f) in enumerate(zip(keys, seqs, frames, strict=True))]
    (folder / "seq_info.csv").write_text(SEQ + "\n" + "\n".join(rows) + "\n")
    rows = [f"{i},{k},144.96,-37.81,90.0,1500000000000,False" for i, k in enumerate(keys)]
    (folder / "raw.csv").write_text(RAW + "\n" + "\n".join(rows) + "\n")
    if images:
        (folder / "images").mkdir()
        for k in keys:
            (folder / "images" / f"{k}.jpg").write_bytes(b"")


def city(root, name, n_db=6, n_q=5, prefix=""):
    """A city with database keys in two sequences (the second with a frame gap) and a query of one sequence."""
    base = root / "train_val" / name
    db = [f"{prefix}db{c}Xk_{i}" for i, c in enumerate("qwerty"[:n_db])]
    write_side(base / "database", db, 320000 + 2.0 * np.arange(n_db), ["sA", "sA", "sA", "sB", "sB", "sB"][:n_db],
               [0, 1, 2, 5, 6, 8][:n_db])
    q = [f"{prefix}q{i}-Zz" for i in range(n_q)]
    write_side(base / "query", q, 320000.5 + 2.0 * np.arange(n_q), ["sQ"] * n_q, list(range(n_q)))
    return base, db, q


def describe(folder, keys, dim=4):
    """Descriptors in the images folder's sorted order (as VPR-methods-evaluation saves them): row of key
    k holds its index in ``keys`` + 1, so a wrong match shows."""
    order = sorted(keys)
    desc = np.zeros((len(keys), dim), np.float32)
    for row, k in enumerate(order):
        desc[row, 0] = keys.index(k) + 1
    desc[:, 1] = 1
    np.save(folder / "desc.npy", desc)
    return folder / "desc.npy"


def test_side_joins_seq_info_with_postprocessed(tmp_path):
    base, db, _ = city(tmp_path, "melbourne")
    side = read_msls_side(base / "database")
    assert side.keys == db
    assert np.allclose(side.positions[:, 0], 320000 + 2.0 * np.arange(6)) and np.all(side.positions[:, 1] == 5813000)
    # sA frames 0,1,2 | sB frames 5,6 | sB frame 8 (a gap breaks a sequence, as MSLS's arange_as_seq does)
    assert side.seq_bounds.tolist() == [[0, 3]] * 3 + [[3, 5]] * 2 + [[5, 6]]


def test_from_msls_cli_round_trip(tmp_path):
    base, db, q = city(tmp_path, "melbourne")
    ref, qry = describe(base / "database", db), describe(base / "query", q)
    out = tmp_path / "ds"
    assert main(["-q", "dataset", "from-msls", str(tmp_path), "--city", "melbourne", "--ref-desc", str(ref),
                 "--query-desc", str(qry), "--out", str(out)]) == 0
    ds = load_dataset(out)
    assert ds.radius == 20 and ds.position_unit == "metres" and ds.extra["preset"] == "msls"
    assert ds.extra["source"]["cities"] == ["melbourne"]
    assert ds.splits == {"train": {"reference": (0, 6), "query": (0, 5)}}  # melbourne: the paper's train city
    assert ds.reference.names[1] == f"melbourne/database/images/{db[1]}.jpg"
    assert np.asarray(ds.reference.descriptors)[:, 0].tolist() == [1, 2, 3, 4, 5, 6]  # matched by key
    assert np.asarray(ds.query.descriptors)[:, 0].tolist() == [1, 2, 3, 4, 5]
    assert ds.reference.seq_bounds[4].tolist() == [3, 5] and ds.query.seq_bounds[0].tolist() == [0, 5]


def test_paper_cities_get_their_roles_and_hdf5_names(tmp_path):
    city(tmp_path, "melbourne")
    city(tmp_path, "austin", prefix="a")
    mel_db = read_msls_side(tmp_path / "train_val/melbourne/database")
    aus_db = read_msls_side(tmp_path / "train_val/austin/database")
    keys = mel_db.keys + aus_db.keys  # one HDF5 for both cities' databases, names as hloc-style paths
    with h5py.File(tmp_path / "db.h5", "w") as h:
        h["descriptors"] = np.eye(len(keys), 4, dtype=np.float32) + 1
        h["names"] = np.array([f"images/{k}.jpg" for k in keys[::-1]], dtype="S")
    qfiles = [describe(tmp_path / f"train_val/{c}/query", read_msls_side(tmp_path / f"train_val/{c}/query").keys)
              for c in ("melbourne", "austin")]
    ds = dataset_from_msls(tmp_path, ["melbourne", "austin"], [str(tmp_path / "db.h5")], [str(f) for f in qfiles])
    assert ds.splits == {"train": {"reference": (0, 6), "query": (0, 5)},
                         "val": {"reference": (6, 12), "query": (5, 10)}}
    assert ds.reference.seq_bounds[6:].tolist() == [[6, 9]] * 3 + [[9, 11]] * 2 + [[11, 12]]
    assert len(ds.split("val").query) == 5
    assert expand_cities(["paper-test"]) == ["amman", "boston", "sf", "cph"]


def test_raw_csv_lat_lon_when_no_postprocessed(tmp_path):
    base, db, q = city(tmp_path, "melbourne")
    (base / "database" / "postprocessed.csv").unlink()
    side = read_msls_side(base / "database")
    assert 320000 < side.positions[0, 0] < 322000 and 5.8e6 < side.positions[0, 1] < 5.82e6  # UTM 55H, Melbourne


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("dbwXk_1,sA,1", "dbwXk_1,sA,one"), r"line 3: frame_number must be int"),
    (lambda t: t.replace("dbwXk_1", "dbqXk_0"), r"key 'dbqXk_0' on lines 2 and 3"),
    (lambda t: t.replace("dbwXk_1,sA,1", "dbwXk_1,sA"), r"line 3: 3 fields, but the header has 4"),
])
def test_bad_seq_info_is_refused_with_the_line(tmp_path, edit, match):
    base, _, _ = city(tmp_path, "melbourne")
    f = base / "database" / "seq_info.csv"
    f.write_text(edit(f.read_text()))
    with pytest.raises(DatasetError, match=match):
        read_msls_side(base / "database")


def test_keys_missing_from_a_file_or_a_descriptor_are_named(tmp_path):
    base, db, q = city(tmp_path, "melbourne")
    f = base / "database" / "postprocessed.csv"
    f.write_text("\n".join(f.read_text().splitlines()[:-1]) + "\n")
    with pytest.raises(DatasetError, match=rf"seq_info.csv key '{db[-1]}' is not in postprocessed.csv"):
        read_msls_side(base / "database")
    base, db, q = city(tmp_path / "b", "melbourne")
    np.save(tmp_path / "short.npy", np.ones((5, 4), np.float32))
    (tmp_path / "short.txt").write_text("\n".join(f"{k}.jpg" for k in db[:5]))
    with pytest.raises(DatasetError, match=rf"first: '{db[5]}'"):
        dataset_from_msls(tmp_path / "b", ["melbourne"], [str(tmp_path / "short.npy")], [str(describe(
            base / "query", q))], ref_names=[str(tmp_path / "short.txt")])


def test_test_city_and_unknown_city_are_refused(tmp_path, capsys):
    write_side(tmp_path / "test" / "miami" / "database", ["k0"], [0.0], ["s"], [0])
    (tmp_path / "test" / "miami" / "database" / "postprocessed.csv").unlink()
    (tmp_path / "test" / "miami" / "database" / "raw.csv").unlink()
    with pytest.raises(DatasetError, match="MSLS withholds the test cities' positions"):
        read_msls_side(tmp_path / "test" / "miami" / "database")
    with pytest.raises(DatasetError, match=r"MSLS city 'paris' not found .* found: miami"):
        dataset_from_msls(tmp_path, ["paris"], ["x.npy"], ["y.npy"])
    with pytest.raises(ConfigError, match="2 --ref-desc files for 3 MSLS cities"):
        dataset_from_msls(tmp_path, ["a", "b", "c"], ["x.npy", "y.npy"], ["y.npy"])
    with pytest.raises(ConfigError, match="'cph' is given twice"):
        expand_cities(["copenhagen", "cph"])


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("dbwXk_1,sA,1", "dbwXk_1,sA,1" + "0" * 30), r"line 3: frame_number must be int numbers "
                                                                      r"\(in 0\.\.\d+\), got \['10{30}'\]"),
    (lambda t: t.replace("dbwXk_1,sA,1", "dbwXk_1,sA,1e30"), r"line 3: frame_number must be int numbers"),
    (lambda t: t.replace("dbwXk_1,sA,1", "dbwXk_1,sA,-9223372036854775808"), r"line 3: frame_number must be int"),
    (lambda t: t.replace("dbwXk_1", "dbwXk_1\x1b[2J"), r"line 3: key 'dbwXk_1\\x1b\[2J' is not an image key"),
    (lambda t: t.replace("dbwXk_1", "../../etc/x"), r"line 3: key '\.\./\.\./etc/x' is not an image key"),
    (lambda t: t.replace("dbwXk_1", "db\x00"), r"line 3: key 'db\\x00' is not an image key"),
])
def test_hostile_seq_info_is_refused_with_the_line(tmp_path, edit, match):
    """A frame number beyond int64 (an OverflowError before) or one whose difference wraps around, and keys that
    would be written into image names raw (escapes, '/', NUL): one line naming the line."""
    base, _, _ = city(tmp_path, "melbourne")
    f = base / "database" / "seq_info.csv"
    f.write_text(edit(f.read_text()))
    with pytest.raises(DatasetError, match=match):
        read_msls_side(base / "database")


@pytest.mark.parametrize("value", ["nan", "inf", "1e300"])
def test_positions_out_of_range_are_refused(tmp_path, value):
    base, _, _ = city(tmp_path, "melbourne")
    f = base / "database" / "postprocessed.csv"
    f.write_text(f.read_text().replace("320002.00", value))
    with pytest.raises(DatasetError, match=rf"line 3: easting/northing must be float numbers \(finite, within "
                                           rf"±1e\+12\), got \['{value}', '5813000.00'\]"):
        read_msls_side(base / "database")


@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_msls_side_gives_a_side_or_one_error(tmp_path_factory, data):
    base, _, _ = city(tmp_path_factory.mktemp("msls"), "melbourne")
    name = data.draw(st.sampled_from(["seq_info.csv", "postprocessed.csv"]))
    f = base / "database" / name
    f.write_bytes(data.draw(mutated(f.read_bytes())))
    try:
        side = read_msls_side(base / "database")
    except DatasetError:
        return
    assert np.isfinite(side.positions).all() and len(side.keys) == len(side.seq_bounds)
