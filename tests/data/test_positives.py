"""Explicit positives: CSR structure vs naive loops, readers (JSON, CSV, pickled object .npy), dataset
round trip and splits, and evaluation that uses them instead of the radius."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from conftest import mutated, read_mutated
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.positives import Positives, read_positives
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate

lists_st = st.lists(st.lists(st.integers(-1, 12), max_size=5), min_size=1, max_size=8)


@given(lists_st)
@settings(max_examples=60, deadline=None)
def test_from_lists_select_hits_vs_loops(lists):
    if any(len(row) > 2 and set(row) <= {0, 1} for row in lists):  # a 0/1 matrix row: refused, not read as indices
        with pytest.raises(DatasetError, match="reference indices repeat"):
            Positives.from_lists(lists)
        return
    p = Positives.from_lists(lists)
    want = [sorted({x for x in row if x >= 0}) for row in lists]
    assert [p.of(i).tolist() for i in range(len(p))] == want
    rng = np.random.default_rng(len(lists))
    q_idx = rng.permutation(len(lists))[: max(1, len(lists) // 2)]
    r_idx = rng.permutation(13)[:7]
    sub = p.select(q_idx, r_idx)
    for m, q in enumerate(q_idx):
        expect = sorted(int(np.flatnonzero(r_idx == r)[0]) for r in want[q] if r in r_idx)
        assert sub.of(m).tolist() == expect
    retrieved = rng.integers(-1, 13, size=(len(lists), 4))
    got = p.hits(retrieved)
    for m in range(len(lists)):
        for k in range(4):
            assert got[m, k] == (retrieved[m, k] >= 0 and retrieved[m, k] in want[m])
    mask = p.mask(13)
    assert mask.sum() == sum(len(w) for w in want)


def test_check_errors():
    p = Positives.from_lists([[0, 5], []])
    with pytest.raises(DatasetError, match="2 rows of positives for 3 query images"):
        p.check(3, 10)
    with pytest.raises(DatasetError, match="query 0 lists reference 5, but the reference traverse has 4 images"):
        p.check(2, 4)
    with pytest.raises(DatasetError, match="must be integers"):
        Positives.from_lists([[0.5]])
    with pytest.raises(DatasetError, match="negative"):
        Positives.from_lists([[-3]])


def test_sets_of_indices_are_their_members(rng):
    """Positives as sets ([{0}, {1}, ...]) were refused with 'reference indices must be integers, got {0}', while
    the pickle reader takes sets."""
    from seqnet.data.positives import as_positives

    lists = [set(rng.integers(-1, 9, size=int(rng.integers(0, 4))).tolist()) for _ in range(12)]
    lists[3] = frozenset({7, 2})
    got = as_positives(lists, 12, 9)
    assert [got.of(i).tolist() for i in range(12)] == [sorted(x for x in row if x >= 0) for row in lists]
    with pytest.raises(DatasetError, match=r"query 0: reference indices must be integers, got \{"):
        as_positives([{"a", 1}], 1, 9)


def test_read_json_csv_npy(tmp_path):
    (tmp_path / "p.json").write_text(json.dumps([[0, 1], [1, 2, 3], [], [-1], 4]))
    p = read_positives(tmp_path / "p.json")
    assert [p.of(i).tolist() for i in range(5)] == [[0, 1], [1, 2, 3], [], [], [4]]
    (tmp_path / "p.csv").write_text("query,reference\n0,1\n0,0\n2,5\n")
    p = read_positives(tmp_path / "p.csv")
    assert [p.of(i).tolist() for i in range(3)] == [[0, 1], [], [5]]
    obj = np.empty(3, dtype=object)
    obj[:] = [np.array([0, 1]), np.array([], dtype=np.int64), np.array([7])]
    np.save(tmp_path / "p.npy", obj, allow_pickle=True)
    p = read_positives(tmp_path / "p.npy")
    assert [p.of(i).tolist() for i in range(3)] == [[0, 1], [], [7]]
    np.save(tmp_path / "dense.npy", np.array([[0, 1], [2, -1]]))
    assert read_positives(tmp_path / "dense.npy").of(1).tolist() == [2]


class Evil:
    def __reduce__(self):
        return (print, ("pwned",))


def test_pickled_code_is_refused(tmp_path, capsys):
    obj = np.empty(1, dtype=object)
    obj[0] = Evil()
    np.save(tmp_path / "evil.npy", obj, allow_pickle=True)
    with pytest.raises(DatasetError, match="refusing builtins.print"):
        read_positives(tmp_path / "evil.npy")
    assert "pwned" not in capsys.readouterr().out
    (tmp_path / "raw.npy").write_bytes(b"\x93NUMPY\x01\x00v\x00{'descr': '|O', 'fortran_order': False, 'shape': (1,), }"
                                       .ljust(128, b" ")[:127] + b"\n" + pickle.dumps(Evil()))
    with pytest.raises(DatasetError):
        read_positives(tmp_path / "raw.npy")


@pytest.mark.parametrize("name, content, pattern", [
    ("p.json", "{bad", "not valid JSON"),
    ("p.json", '{"a": 1}', "expected a JSON list"),
    ("p.json", '[["x"]]', "must be integers"),
    ("p.csv", "0,1\n0,x\n", "line 2: expected 'query,reference'"),
    ("p.csv", "query,reference\n", "no query,reference pairs"),
    ("p.csv", "-1,2\n", "negative"),
    ("p.txt", b"\xff\xfe", "not UTF-8"),
    ("p.pkl", "x", "as a pickle"),
    ("p.gt", "x", "must be .json, .csv, .npy, .pkl or .npz"),
    ("p.npy", "not numpy", "cannot read"),
])
def test_reader_errors(tmp_path, name, content, pattern):
    f = tmp_path / name
    f.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(DatasetError, match=pattern):
        read_positives(f)


def frame_dataset(n=30, positives=None, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((n, 8)).astype(np.float32)
    ref = Traverse(base, np.arange(n, dtype=float))
    qry = Traverse((base + 0.3 * rng.standard_normal((n, 8))).astype(np.float32), np.arange(n, dtype=float))
    return Dataset(ref, qry, radius=1.0, splits={"test": {"reference": (5, 25), "query": (10, 20)}},
                   positives=positives)


def test_dataset_round_trip_and_split(tmp_path):
    pos = Positives.from_lists([[i, i + 1] if i % 3 else [] for i in range(29)] + [[29]])
    root = save_dataset(frame_dataset(positives=pos), tmp_path / "ds")
    back = load_dataset(root)
    np.testing.assert_array_equal(back.positives.indptr, pos.indptr)
    np.testing.assert_array_equal(back.positives.indices, pos.indices)
    sub = back.split("test")
    for m, q in enumerate(range(10, 20)):
        assert sub.positives.of(m).tolist() == [r - 5 for r in pos.of(q) if 5 <= r < 25]
    with pytest.raises(DatasetError, match="rows of positives"):
        frame_dataset(positives=Positives.from_lists([[0]]))


def test_evaluate_with_positives_equal_to_radius_gives_same_recall():
    n = 30
    radius_pos = Positives.from_lists([[j for j in range(n) if abs(i - j) <= 1] for i in range(n)])
    conf = EvalConfig(methods=("single", "raw+seqmatch", "hvpr-delta:raw+seqmatch"), seq_len=3, device="cpu")
    a = evaluate(frame_dataset(), conf)
    b = evaluate(frame_dataset(positives=radius_pos), conf)
    for name in conf.methods:
        ra, rb = ({k: v for k, v in ev.results["methods"][name].items() if k != "timing_ms"} for ev in (a, b))
        assert ra == rb


def test_evaluate_uses_positives_not_the_radius():
    n = 30
    shifted = Positives.from_lists([[(i + 10) % n] for i in range(n)])  # wrong on purpose: far from the radius
    conf = EvalConfig(methods=("single",), seq_len=1, ks=(1, 30), device="cpu", split="all")
    ev = evaluate(frame_dataset(positives=shifted), conf)
    hits = ev.truth.hits(ev.retrieved["single"])
    assert ev.results["methods"]["single"]["recall@30"] == 1.0
    np.testing.assert_array_equal(hits.any(axis=1), np.ones(n, bool))
    for m in range(n):
        assert (ev.retrieved["single"][m][hits[m]] == (m + 10) % n).all()


def test_positives_without_a_radius_imply_one():
    from seqnet.data.convert import assemble_dataset, positives_radius
    from seqnet.data.traverse import Traverse

    pos = np.arange(20, dtype=np.float64)[:, None] * 2.0  # a frame every 2 m
    rows = [[max(0, i - 2), i, min(19, i + 2)] for i in range(20)]  # positives span 4 frames = 8 m
    p = Positives.from_lists(rows)
    assert positives_radius(p, pos) == 4.0
    assert positives_radius(Positives.from_lists([[i] for i in range(20)]), pos) == 2.0  # one positive: one step
    t = Traverse(np.eye(20, 8, dtype=np.float32) + 0.1, pos)
    assert assemble_dataset(t, t, "metres", positives=p).radius == 4.0
    with pytest.raises(ConfigError, match="no localisation radius"):
        assemble_dataset(t, t, "metres")


@pytest.mark.parametrize("dtype", [np.uint8, np.int64, np.float32, bool])
def test_a_dense_ground_truth_matrix_is_read_as_the_matrix(tmp_path, dtype):
    gt = np.zeros((4, 6), dtype=dtype)
    gt[0, 0] = gt[1, 1] = gt[1, 2] = gt[3, 5] = 1
    np.save(tmp_path / "gt.npy", gt)
    pos = read_positives(tmp_path / "gt.npy")
    assert [pos.indices[a:b].tolist() for a, b in zip(pos.indptr[:-1], pos.indptr[1:], strict=True)] == \
        [[0], [1, 2], [], [5]]
    pos.check(4, 6)
    with pytest.raises(DatasetError, match="a ground-truth matrix of 6 columns for 7 reference images"):
        pos.check(4, 7)


def test_padded_index_rows_and_refusals(tmp_path):
    np.save(tmp_path / "idx.npy", np.array([[3, 4, -1], [2, -1, -1]]))
    pos = read_positives(tmp_path / "idx.npy")
    assert pos.indices.tolist() == [3, 4, 2] and pos.n_refs is None
    np.save(tmp_path / "bad.npy", np.array([[0.5, 2.0]]))
    with pytest.raises(DatasetError, match="neither a 0/1 ground-truth matrix nor integer reference indices"):
        read_positives(tmp_path / "bad.npy")


def test_vpr_bench_ground_truth_new(tmp_path):
    """VPR-Bench's layout: an object array of [query index, [reference indices]] rows (np.save, allow_pickle)."""
    rows = np.empty((3, 2), dtype=object)
    rows[0] = [1, [2, 3]]
    rows[1] = [0, [0]]
    rows[2] = [2, 4]  # a single reference as a scalar
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    pos = read_positives(tmp_path / "ground_truth_new.npy")
    assert len(pos) == 3
    assert [pos.indices[a:b].tolist() for a, b in zip(pos.indptr[:-1], pos.indptr[1:], strict=True)] == \
        [[0], [2, 3], [4]]
    rows[2, 0] = 1  # query 1 twice, query 2 missing
    np.save(tmp_path / "dup.npy", rows, allow_pickle=True)
    with pytest.raises(DatasetError, match="every query 0..2 once"):
        read_positives(tmp_path / "dup.npy")
    with pytest.raises(DatasetError, match="every query 0..2 once") as e:
        read_positives(tmp_path / "dup.npy")
    assert "count from 1" not in str(e.value)
    rows[:, 0] = [2, 1, 3]  # queries numbered from 1: the 'subtract 1' hint the CSV and JSON routes give
    np.save(tmp_path / "one.npy", rows, allow_pickle=True)
    with pytest.raises(DatasetError, match=r"every query 0..2 once .*seems to count from 1.*subtract 1"):
        read_positives(tmp_path / "one.npy")


def test_vpr_tutorial_gt_npz(tmp_path):
    """VPR_Tutorial's GT.npz: GThard [N_db, N_q] (bool), GTsoft beside it."""
    hard = np.zeros((5, 3), bool)
    hard[0, 0] = hard[1, 0] = hard[4, 2] = True
    np.savez(tmp_path / "GT.npz", GThard=hard, GTsoft=hard | np.roll(hard, 1, axis=0))
    pos = read_positives(tmp_path / "GT.npz").check(3, 5)
    assert [pos.indices[a:b].tolist() for a, b in zip(pos.indptr[:-1], pos.indptr[1:], strict=True)] == \
        [[0, 1], [], [4]]
    # GTsoft: the soft positives, stored as GThard | GTsoft (VPR_Tutorial's soft set includes the hard one)
    assert [pos.soft.of(q).tolist() for q in range(3)] == [[0, 1, 2], [], [0, 4]]
    sel = pos.select(np.array([0, 2]), np.array([1, 2, 4]))  # a split keeps the soft positives, renumbered
    assert [sel.of(q).tolist() for q in range(2)] == [[0], [2]]
    assert [sel.soft.of(q).tolist() for q in range(2)] == [[0, 1], [2]]
    np.savez(tmp_path / "other.npz", gt=hard)
    with pytest.raises(DatasetError, match="needs VPR_Tutorial's 'GThard'"):
        read_positives(tmp_path / "other.npz")
    np.savez(tmp_path / "bad.npz", GThard=hard, GTsoft=hard[:4])
    with pytest.raises(DatasetError, match=r"GTsoft has shape \(4, 3\) but GThard \(5, 3\)"):
        read_positives(tmp_path / "bad.npz")
    np.savez(tmp_path / "wide.npz", GThard=hard, GTsoft=np.eye(6, 3, dtype=bool))
    with pytest.raises(DatasetError, match=r"GTsoft has shape"):
        read_positives(tmp_path / "wide.npz")
    bad_soft = Positives(pos.indptr, pos.indices, soft=Positives.from_lists([[0, 9], [], [4]]))
    with pytest.raises(DatasetError, match=r"\(soft positives\): query 0 lists reference 9, but the reference"):
        bad_soft.check(3, 5)


def test_soft_positives_are_saved_with_the_dataset(tmp_path, synth_dataset):
    """GT.npz through `dataset from-utm-names --positives`: hard and soft positives round-trip in the dataset."""
    import dataclasses

    from seqnet.data.io import load_dataset, save_dataset

    n_q, n_r = len(synth_dataset.query), len(synth_dataset.reference)
    hard = np.zeros((n_r, n_q), bool)
    hard[np.arange(n_q) % n_r, np.arange(n_q)] = True
    soft = np.roll(hard, 1, axis=0)
    np.savez(tmp_path / "GT.npz", GThard=hard, GTsoft=soft)
    pos = read_positives(tmp_path / "GT.npz")
    ds = load_dataset(save_dataset(dataclasses.replace(synth_dataset, positives=pos), tmp_path / "ds"))
    assert ds.positives.of(3).tolist() == [3] and ds.positives.soft.of(3).tolist() == [3, 4]
    assert ds.split("test").positives.soft is not None


@pytest.mark.parametrize("text, match", [
    ("50000000,1\n", r"query index 50000000 is beyond what 1 pairs can describe \(at most 1000016 queries"),
    ("1000000000000,1\n", r"query index 1000000000000 is beyond what 1 pairs"),
    ("1,1\n0,4611686018427387905\n", r"line 2: reference index 4611686018427387905 is too large"),
    ("0," + "9" * 30 + "\n", r"line 1: expected 'query,reference' \(two integers\)"),
    ("0,1\n²,1\n", r"line 2: expected 'query,reference' \(two integers\), got '²,1'"),
    ("0,-2\n", r"reference index -2 is negative"),
])
def test_csv_query_indices_are_bounded_by_the_file(tmp_path, text, match):
    """One line ``50000000,1`` built 5e7 empty lists (and 10**12 never finished): the number of queries a CSV may
    imply is bounded by its number of pairs, and every index is checked before anything is allocated."""
    (tmp_path / "p.csv").write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_positives(tmp_path / "p.csv")


def test_csv_pairs_build_the_csr_at_once(tmp_path):
    (tmp_path / "p.csv").write_text("3,7\n0,2\n3,7\n0,1\n5,-1\n")
    p = read_positives(tmp_path / "p.csv")
    assert p.indptr.tolist() == [0, 2, 2, 2, 3, 3, 3] and p.indices.tolist() == [1, 2, 7]
    big = Positives.from_pairs(np.array([0, 1]), np.array([2**62, 3]), 2)  # no product of indices overflows
    assert big.indices.tolist() == [2**62, 3]


@settings(max_examples=200, deadline=None)
@given(data=mutated(b"query,reference\n0,1\n0,2\n2,5\n3,-1\n"))
def test_fuzzed_csv_gives_positives_or_one_error(tmp_path_factory, data):
    p = read_mutated(read_positives, tmp_path_factory.mktemp("p") / "p.csv", data)
    assert p is None or len(p) <= 16 * 8 + 10**6 and (p.indices >= 0).all()


def test_a_file_counted_from_one_is_told_so():
    """Own-data hostile 52 L8: a pairs CSV of queries and references 1..120 was refused as '121 rows of positives
    for 120 query images' with no word of its indices starting at 1."""
    one_based = Positives.from_pairs(np.arange(1, 121), np.arange(1, 121), 121)
    with pytest.raises(DatasetError, match=r"121 rows of positives for 120 query images .*count from 1.*subtract 1"):
        one_based.check(120, 120, "pos1.csv")
    refs = Positives.from_lists([[i + 1] for i in range(120)])  # references counted from 1 only
    with pytest.raises(DatasetError, match=r"lists reference 120, .*count from 1"):
        refs.check(120, 120)
    with pytest.raises(DatasetError) as e:
        Positives.from_lists([[0]] * 5).check(4, 4)  # one row too many, but row 0 is used: no such hint
    assert "count from 1" not in str(e.value)
