"""Reading seqNet .db struct files and converting them (shared struct files, synthetic descriptors)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_data

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
