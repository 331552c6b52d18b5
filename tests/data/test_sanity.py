"""Likely mistakes in a dataset (seqnet.data.sanity): frame-aligned traverses that cannot pair up are refused;
the query being the reference, splits sharing queries and constant positions are each one warning line."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import DatasetError
from seqnet.data.positives import Positives
from seqnet.data.sanity import (
    check_frame_aligned,
    copies,
    dataset_warnings,
    duplicated_rows,
    review,
    shared_queries,
)
from seqnet.data.sanity.copies import _copies, _row_hashes
from seqnet.data.traverse import Dataset, Traverse


def make(ref: np.ndarray, qry: np.ndarray, r_pos=None, q_pos=None, splits=None, radius=1.0, **kw) -> Dataset:
    r_pos = np.arange(len(ref), dtype=float)[:, None] if r_pos is None else r_pos
    q_pos = np.arange(len(qry), dtype=float)[:, None] if q_pos is None else q_pos
    return Dataset(Traverse(ref, r_pos, [f"r{i:03d}.png" for i in range(len(ref))], name="reference"),
                   Traverse(qry, q_pos, [f"q{i:03d}.png" for i in range(len(qry))], name="query"), radius,
                   splits=splits or {}, name="d", **kw)


@pytest.fixture
def desc():
    return np.random.default_rng(0).random((20, 6)).astype(np.float32) + 0.1


def test_a_clean_dataset_has_no_warning(desc):
    assert dataset_warnings(make(desc, desc[::-1] * 0.9, splits={"train": {"query": (0, 10)},
                                                                 "test": {"query": (10, 20)}})) == []


def test_the_query_being_the_reference_is_warned(desc):
    [line] = dataset_warnings(make(desc, desc.copy()))
    assert line.startswith("d: the query images are the reference images (identical descriptors, row for row): "
                           "every metric is trivially perfect")
    at = np.array([5, 3, 9], dtype=float)[:, None]  # copies, in another order, at their own places: as trivial
    [line] = dataset_warnings(make(desc, desc[[5, 3, 9]], q_pos=at))
    assert "every one of the 3 query descriptors is an exact copy of a reference descriptor" in line
    assert dataset_warnings(make(desc, desc[[5, 3, 9]], q_pos=at + 0.5)) != []  # within the radius
    pos = Positives.from_lists([[5], [3], [9]])
    assert len(dataset_warnings(make(desc, desc[[5, 3, 9]], positives=pos))) == 1


def test_copies_elsewhere_on_the_route_are_not_trivial(desc):
    """A training set that uses each traverse both ways (the benchmark's symmetric training): every query is a
    reference row too, but far from its place, so nothing is trivially perfect (it was warned)."""
    ds = make(np.concatenate([desc[:10], desc[10:]]), np.concatenate([desc[10:], desc[:10]]),
              q_pos=np.arange(20, dtype=float)[:, None])
    assert dataset_warnings(ds) == []
    assert dataset_warnings(make(desc, desc[[5, 3, 9]])) == []  # query 0 (place 0) is reference 5's copy
    assert dataset_warnings(make(desc, desc[[5, 3, 9]], positives=Positives.from_lists([[4], [3], [9]]))) == []
    assert dataset_warnings(make(desc, np.concatenate([desc[[5, 3]], desc[:1] + 1e-3]))) == []


def test_row_hashes_vs_a_loop(desc):
    rows = np.concatenate([desc, desc[[2, 7]], desc[:3] + 1])
    h = _row_hashes(rows)
    for i in range(len(rows)):
        for j in range(len(rows)):
            assert (h[i] == h[j]) == (rows[i].tobytes() == rows[j].tobytes())


def test_copy_of_vs_a_loop(monkeypatch):
    """Every query row's identical reference row, found by a hash of its first columns then compared whole, as
    a loop over all pairs finds it; small blocks (several per array) and a shared prefix included."""

    monkeypatch.setattr(copies, "BLOCK_BYTES", 3 * 96 * 8)  # blocks of 3 rows compared, 12 hashed
    rng = np.random.default_rng(3)
    ref = rng.random((30, 24)).astype(np.float32)
    ref[7, :16] = ref[8, :16]  # rows 7 and 8 share the hashed prefix
    qry = ref[rng.integers(0, 30, 17)]
    match = _copies(ref, qry)
    for m, q in enumerate(qry):
        assert [r for r in range(30) if ref[r].tobytes() == q.tobytes()] == [match[m]]
    assert _copies(ref, ref[[8, 7, 8]]).tolist() == [8, 7, 8]
    changed = qry.copy()
    changed[11, 20] += 1  # same prefix, another row: no copy
    assert _copies(ref, changed)[11] == -1  # the one changed row has no copy


def test_splits_sharing_queries_are_named(desc):
    splits = {"train": {"query": (0, 12)}, "val": {"query": (10, 16)}, "test": {"query": (15, 20)}}
    [line] = dataset_warnings(make(desc, desc * 0.5, splits=splits))
    assert ("splits train (queries 0:12) and val (queries 10:16) share 2; val (queries 10:16) and test (queries "
            "15:20) share 1 queries") in line and "optimistic" in line


def test_shared_queries_of_named_splits_and_ranges(desc):
    ds = make(desc, desc * 0.5, splits={"train": {"query": (0, 12)}, "val": {"query": (10, 16)}})
    assert "train (queries 0:12) and val (queries 10:16) share 2" in shared_queries(ds, ["train", "val"])
    assert "share 6" in shared_queries(ds, ["all", "val"]) and shared_queries(ds, ["val", "14:20"]) is not None
    assert shared_queries(ds, ["train", "12:20"]) is None and shared_queries(ds, ["train", "nope"]) is None


def test_positions_in_degrees_are_named(desc):
    deg = np.stack([np.full(20, 10.0), 63 + np.arange(20) * 9e-5], axis=1)
    [line] = dataset_warnings(make(desc, desc * 0.5, deg, deg, radius=25.0))
    assert "positions look like degrees (latitude/longitude), not metres" in line and "constant GPS" not in line


def test_shuffled_query_rows_are_warned(desc):
    rng = np.random.default_rng(0)
    big = rng.random((200, 4)).astype(np.float32) + 0.1
    shuffled = np.arange(200.0)[rng.permutation(200), None]
    [line] = dataset_warnings(make(big, big * 0.5, q_pos=shuffled))
    assert line.startswith("d: ") and "the query's consecutive frames lie far apart" in line
    assert dataset_warnings(make(big, big * 0.5)) == []


def test_duplicated_rows_vs_a_loop(desc, monkeypatch):
    rng = np.random.default_rng(3)
    rows = rng.random((300, 5)).astype(np.float32)
    rows[rng.integers(0, 300, 40)] = rows[rng.integers(0, 300, 40)]
    naive = 300 - len({r.tobytes() for r in rows})
    assert duplicated_rows(rows, "query").startswith(f"{naive} of the 300 query rows are exact duplicates")
    assert duplicated_rows(rows[:1], "query") is None and duplicated_rows(desc, "query") is None
    many = np.random.default_rng(4).random((5000, 4)).astype(np.float32)
    many[1::2] = many[0::2]  # every frame twice: found in runs of consecutive rows beyond the byte budget
    monkeypatch.setattr(copies, "DUPLICATES_BYTES", 1)
    n, rest = duplicated_rows(many, "query").split(" ", 1)
    assert 7 * 127 <= int(n) <= 896 and rest.startswith("of 1792 checked (of 5000) query rows are exact duplicates")
    [line] = dataset_warnings(make(desc, np.concatenate([desc[:10] * 0.5] * 2)))
    assert "10 of the 20 query rows are exact duplicates" in line


def test_constant_positions_are_warned_unless_positives_decide(desc):
    same = np.full((20, 2), 5.0)
    [line] = dataset_warnings(make(desc, desc * 0.5, same, same, radius=25.0))
    assert ("all 20 reference and 20 query positions lie within 0 metres of each other, inside the radius 25: every "
            "reference is within the radius of every query, so R@K is 1 trivially") in line
    truth = Positives.from_lists([[i] for i in range(20)])
    assert dataset_warnings(make(desc, desc * 0.5, same, same, radius=25.0, positives=truth)) == []


def test_frame_aligned_traverses_must_pair_up(desc, caplog):
    with pytest.raises(DatasetError, match=r"--frame-aligned: query frame i is the place of reference frame i, but the "
                                           r"reference has 3 images and the query 2, .* --positives FILE"):
        check_frame_aligned(["a", "b", "c"], ["a", "c"])
    with pytest.raises(DatasetError, match="reference image 1 is 'b' but query image 1 is 'c': an image missing"):
        check_frame_aligned(["a", "b", "c"], ["a", "c", "d"])
    check_frame_aligned(["a", "b"], ["x", "y"])  # named differently: nothing to pair by name
    ds = make(desc, desc[:15] * 0.5, extra={"ground_truth": "frames"})
    with pytest.raises(DatasetError, match="d: frame-aligned ground truth: .* has 20 images and the query 15"):
        review(ds)
    with caplog.at_level("WARNING", logger="seqnet"):
        assert review(make(desc, desc.copy(), extra={"ground_truth": "frames"}))  # named r*/q*: no pairing by name
    assert caplog.messages[0].startswith("d: the query images are the reference images")


def test_frame_aligned_names_that_differ_only_in_zero_padding_pair_up():
    """img1..img200 against img001..img200 (both complete, same natural order): paired by number, said in one
    line; a real gap is still refused, also when no name is spelled alike; equal names say nothing."""
    ref, qry = [f"img{k}.png" for k in range(1, 201)], [f"img{k:03d}.png" for k in range(1, 201)]
    assert check_frame_aligned(ref, qry) == ("--frame-aligned: the names differ only in zero-padding or case "
                                             "(reference 'img1.png', query 'img001.png'): paired by their numbers")
    assert check_frame_aligned(ref, ref) is None and check_frame_aligned(ref[:99], qry[:99]) is not None
    assert check_frame_aligned(["IMG1.PNG"], ["img1.png"]) is not None
    with pytest.raises(DatasetError, match="reference image 4 is 'img5.png' but query image 4 is 'img006.png'"):
        check_frame_aligned(ref[:99], qry[:4] + qry[5:100])  # img005 missing, none spelled alike


def test_video_aligned_ground_truth_must_pair_up_by_count(desc):
    """``from-video --aligned`` records ``"ground_truth": "aligned"``: refused like ``frames`` when the counts
    differ (the hint names the videos' positions), but its frames, named by video time, are not paired by name."""
    with pytest.raises(DatasetError, match=r"d: frame-aligned ground truth: .* reference has 20 images and the query "
                                           r"15, .*\(--ref-positions / --query-positions .* equal length and frame"):
        review(make(desc, desc[:15] * 0.5, extra={"ground_truth": "aligned"}))
    times = make(desc, desc * 0.5, extra={"ground_truth": "aligned"})
    times.reference.names = [f"{i / 10:.6f}" for i in range(20)]  # 10 fps against 25 fps: names in common, differ
    times.query.names = [f"{i / 25:.6f}" for i in range(20)]
    review(times)
    times.extra["ground_truth"] = "frames"  # image folders: the names pair up too
    with pytest.raises(DatasetError, match="reference image 1 is '0.100000' but query image 1 is '0.040000'"):
        review(times)
