"""Query images that are reference images (seqnet.data.sanity.copies): a partial count is said, with its rows, at
build, by ``dataset check`` and per evaluated split; constant frames and copies far from their place stay silent."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.data.positives import Positives
from seqnet.data.sanity import copied_queries, copies, dataset_warnings
from seqnet.data.sanity.copies import _copies, describe_rows
from seqnet.data.traverse import Dataset, Traverse


def make(ref: np.ndarray, qry: np.ndarray, q_pos=None, splits=None, **kw) -> Dataset:
    r_pos = np.arange(len(ref), dtype=float)[:, None]
    q_pos = np.arange(len(qry), dtype=float)[:, None] if q_pos is None else q_pos
    return Dataset(Traverse(ref, r_pos, [f"r{i:03d}.png" for i in range(len(ref))], name="reference"),
                   Traverse(qry, q_pos, [f"q{i:03d}.png" for i in range(len(qry))], name="query"), 1.0,
                   splits=splits or {}, name="d", **kw)


@pytest.fixture
def desc():
    return np.random.default_rng(0).random((40, 6)).astype(np.float32) + 0.1


def test_some_queries_copied_from_the_reference_are_counted(desc):
    qry = desc * 0.9
    qry[10:16] = desc[10:16]  # six query frames filled with the reference's image of their place
    [line] = dataset_warnings(make(desc, qry))
    assert line.startswith("d: 6 of the 40 query descriptors (rows 10:16) are exact copies of the reference "
                           "descriptors of their own place (reference images among the query's?): those queries "
                           "are found trivially and R@K is optimistic; hint: check the query images")
    qry = desc * 0.9
    qry[::2] = desc[::2]
    assert "20 of the 40 query descriptors (every 2nd row of 0:39) are exact copies" in copied_queries(make(desc, qry))
    pos = Positives.from_lists([[i] for i in range(40)])
    assert "20 of the 40" in copied_queries(make(desc, qry, positives=pos))


def test_the_count_is_said_per_split(desc):
    qry = desc * 0.9
    qry[15:25] = desc[15:25]
    ds = make(desc, qry, splits={"val": {"query": (0, 20)}, "test": {"query": (20, 40)}})
    assert copied_queries(ds.split("val")).startswith("5 of the 20 query descriptors of d[val] (its rows 15:20)")
    assert copied_queries(ds.split("test")).startswith("5 of the 20 query descriptors of d[test] (its rows 0:5)")


def test_few_far_or_constant_copies_stay_silent(desc):
    qry = desc * 0.9
    qry[[3, 30]] = desc[[3, 30]]  # two: below COPIES_MIN
    assert copied_queries(make(desc, qry)) is None
    qry = desc * 0.9
    qry[10:16] = desc[30:36]  # copies of other places (a traverse used both ways): nothing is found trivially
    assert copied_queries(make(desc, qry)) is None
    pos = Positives.from_lists([[(i + 1) % 40] for i in range(40)])  # the positives say the copy is elsewhere
    qry[10:16] = desc[10:16]
    assert copied_queries(make(desc, qry, positives=pos)) is None
    ref, qry = desc.copy(), desc * 0.9
    ref[5:12] = qry[5:12] = 0.5  # a tunnel's black frames in both traverses: no copied image
    assert copied_queries(make(ref, qry)) is None


def test_copies_vs_a_loop(monkeypatch):
    monkeypatch.setattr(copies, "BLOCK_BYTES", 3 * 96 * 8)  # several blocks per array
    rng = np.random.default_rng(5)
    ref = rng.random((30, 24)).astype(np.float32)
    qry = rng.random((25, 24)).astype(np.float32)
    qry[rng.choice(25, 12, replace=False)] = ref[rng.integers(0, 30, 12)]
    qry[3] = ref[7][::-1]  # the same sum, another row
    got = _copies(ref, qry)
    for m, q in enumerate(qry):
        same = [r for r in range(30) if ref[r].tobytes() == q.tobytes()]
        assert got[m] == (same[0] if same else -1)


def test_rows_described():
    assert describe_rows(np.array([3, 4, 5, 9, 10])) == "rows 3:6, 9:11"
    assert describe_rows(np.arange(0, 30, 3)) == "every 3rd row of 0:28"
    assert describe_rows(np.r_[0, 2, 5, 9, 20:30]) == "in 5 runs from row 0 to 29, the longest 20:30"


def test_clean_synthetic_dataset_is_silent(synth_dataset):
    assert copied_queries(synth_dataset) is None
    for split in synth_dataset.splits:
        assert copied_queries(synth_dataset.split(split)) is None
