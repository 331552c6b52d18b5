"""The true-match check of every dataset builder: no query with one is refused naming the likely cause (columns
swapped when swapping them helps; degrees; else the distances against the radius); few is one warning line."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from seqnet.core.errors import DatasetError
from seqnet.data.positives import Positives
from seqnet.data.traverse import Dataset, Traverse
from seqnet.pipelines.ground_truth import check_true_matches


def dataset(ref_pos, qry_pos, radius: float, positives: Positives | None = None, unit: str = "metres") -> Dataset:
    ones = [np.ones((len(p), 1), np.float32) for p in (ref_pos, qry_pos)]
    return Dataset(Traverse(ones[0], ref_pos, name="reference"), Traverse(ones[1], qry_pos, name="query"), radius,
                   unit, name="ds", positives=positives)


ROUTE = np.stack([500000 + 10.0 * np.arange(30), 6000000 + 0.5 * np.arange(30)], axis=1)


def test_matches_pass_and_swapped_columns_are_named():
    assert check_true_matches(dataset(ROUTE, ROUTE + [2.0, 0.0], 5.0)) is None
    with pytest.raises(DatasetError, match=r"^ds: none of the 30 queries has a reference within the radius 5 metres"
                                           r".*with one traverse's two position columns swapped 30 of 30 queries "
                                           "would have one"):
        check_true_matches(dataset(ROUTE, ROUTE[:, ::-1] + [0.0, 2.0], 5.0))


def test_unit_mistakes_say_the_distances_and_degrees():
    with pytest.raises(DatasetError, match=r"the nearest reference to any query is 2.0 metres away \(median over the "
                                           r"queries 2.0 metres\), the radius is 0.0002 metres: positions swapped"):
        check_true_matches(dataset(ROUTE, ROUTE + [2.0, 0.0], 0.0002))
    deg = np.stack([14.0 + 1e-4 * np.arange(30), np.full(30, 66.0)], axis=1)
    with pytest.raises(DatasetError, match="positions look like degrees"):
        check_true_matches(dataset(deg, deg + [0.0, 1e-4], 1e-6))


def test_frames_numbered_differently_are_named():
    """A query CSV numbering its frames from 10000 (file numbers), the reference from 0: said as such, not as swapped
    easting/northing."""
    ref, qry = np.arange(30.0)[:, None], 10000 + 10 * np.arange(30.0)[:, None]
    with pytest.raises(DatasetError, match=r"the two files number their frames differently \(reference from 0, query "
                                           r"from 10000\)\?"):
        check_true_matches(dataset(ref, qry, 1.0, unit="frames"))


def test_few_matches_warn_once_and_empty_positives_are_refused(caplog):
    qry = ROUTE + np.where(np.arange(30) < 10, 2.0, 900.0)[:, None] * [1.0, 0.0]
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        line = check_true_matches(dataset(ROUTE, qry, 5.0))
    assert line.startswith("ds: only 10 of 30 queries (33%) have a reference within the radius 5 metres: ")
    assert [r.getMessage() for r in caplog.records] == [line]
    empty = Positives.from_lists([[] for _ in range(30)])
    with pytest.raises(DatasetError, match="none of the 30 queries has an explicit positive.*check the positives"):
        check_true_matches(dataset(ROUTE, ROUTE, 5.0, empty))


def test_a_sequence_column_follows_the_images_order_not_the_csvs(tmp_path):
    """A positions CSV listed in another order than the images (here reversed): each image gets its own row's
    position and its sequence is the run of equal ids in the images' order (it indexed the CSV-order bounds by
    image position: 'seq_bounds[0] = [3, 6] does not contain image 0')."""
    from types import SimpleNamespace

    from seqnet.pipelines.ground_truth import _csv_positions

    names = [f"f{i}.png" for i in range(6)]
    seqs = ["a", "a", "a", "b", "b", "b"]
    csv = tmp_path / "pos.csv"
    csv.write_text("name,frame,sequence\n" + "".join(f"{names[i]},{i},{seqs[i]}\n" for i in reversed(range(6))))
    pos, bounds, unit, _ = _csv_positions(SimpleNamespace(positions_format="csv"), SimpleNamespace(names=names),
                                          tmp_path, csv, "reference")
    assert unit == "frames" and pos[:, 0].tolist() == list(range(6))
    assert bounds.tolist() == [[0, 3]] * 3 + [[3, 6]] * 3


@pytest.mark.parametrize("order", ["same", "other", "text"])
def test_a_csv_in_another_order_than_the_images_is_said(tmp_path, caplog, order):
    """docs/datasets.md: 'a CSV listed in another order is said by a warning' (from-images said nothing: images
    named 0.5.png, 0.25.png, ... sorted out of time order went by silently); the same order stays silent."""
    from types import SimpleNamespace

    from seqnet.pipelines.ground_truth import _csv_positions

    names = [f"f{i}.png" for i in range(12)]
    rows = {"same": list(range(12)), "other": [0, 2, 1, *range(3, 12)],
            "text": sorted(range(12), key=lambda i: names[i])}[order]  # f0, f1, f10, f11, f2: as ls sorts them
    csv = tmp_path / "pos.csv"
    csv.write_text("name,frame\n" + "".join(f"{names[i]},{i}\n" for i in rows))
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        _csv_positions(SimpleNamespace(positions_format="csv"), SimpleNamespace(names=names), tmp_path / "q", csv,
                       "query")
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    if order in ("same", "text"):  # a CSV sorted as text says nothing of the route's order: silent
        assert not said, said
    else:
        assert len(said) == 1 and "lists the images in another order than the order of the query images" in said[0]
        assert "image 2, 'f2.png', is on line 3, after line 4 (image 1, 'f1.png')" in said[0]


def test_a_csv_with_lat_lon_and_x_y_uses_the_kind_the_other_csv_has(tmp_path, caplog):
    """A query CSV with lat,lon and x,y (GPS and a local odometry frame) against a lat,lon reference: x,y was used
    silently and the error then said the query had easting / northing only; now lat, lon is used, said in one
    line; two CSVs with one kind each stay silent."""
    from types import SimpleNamespace

    from seqnet.pipelines.ground_truth import both_positions

    names = [f"f{i}.png" for i in range(5)]
    ref = tmp_path / "ref.csv"
    ref.write_text("name,lat,lon\n" + "".join(f"{n},63.43,{10.39 + 1e-4 * i}\n" for i, n in enumerate(names)))
    both = tmp_path / "both.csv"
    both.write_text("name,lat,lon,x,y\n" + "".join(f"{n},63.43,{10.39 + 1e-4 * i},{5 * i},0\n"
                                                   for i, n in enumerate(names)))
    conf = SimpleNamespace(ground_truth="csv", positions_format="csv")
    images = (SimpleNamespace(names=names), SimpleNamespace(names=names))
    with caplog.at_level(logging.INFO, logger="seqnet"):
        r, q = both_positions(conf, images, (tmp_path, tmp_path), (ref, both))
    assert r[2] == q[2] == "metres" and np.allclose(r[0], q[0])
    said = [m.getMessage() for m in caplog.records if "position columns" in m.getMessage()]
    assert len(said) == 1 and "lat, lon (degrees): using lat, lon (the kind" in said[0] and "ref.csv has)" in said[0]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="seqnet"):
        both_positions(conf, images, (tmp_path, tmp_path), (ref, ref))
    assert not [m for m in caplog.records if "position columns" in m.getMessage()]


def _pairs_file(tmp_path, n_listed: int, n_refs: int = 200):
    from seqnet.data.positives import read_positives

    f = tmp_path / "ps.csv"
    f.write_text("query,reference\n" + "".join(f"{q},{r}\n" for q in range(n_listed)
                                                for r in (2 * q - 1, 2 * q, 2 * q + 1) if 0 <= r < n_refs))
    return read_positives(f)


@pytest.mark.parametrize("listed", [60, 100])
def test_positives_that_stop_early_and_a_split_with_few_matches_are_warned(tmp_path, caplog, listed):
    """A positives file cut after query 59 of 100 (a truncated export) was accepted silently: 60% overall is above
    the 'fewer than half' check, and the test split 50:100 (10 of 50 matched) was not checked; now both are
    said. The complete file stays silent."""
    positives = _pairs_file(tmp_path, listed)
    ref, qry = (np.arange(n, dtype=np.float64)[:, None] for n in (200, 100))
    ds = dataset(ref, 2 * qry, 1.0, positives, unit="frames")
    ds.splits = {"test": {"reference": (0, 200), "query": (50, 100)}}
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert check_true_matches(ds) is None
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    if listed == 100:
        assert not said
        return
    assert len(said) == 2
    assert "positives give queries 0..59 a match (60 of them) and none of the last 40 of 100 queries: a truncated" \
        in said[0]
    assert "split test (queries 50:100): only 10 of 50 queries (20%) have a true match" in said[1]


@pytest.mark.parametrize(("start", "level"), [(0, None), (1, logging.WARNING), (3, logging.INFO)])
def test_frame_columns_that_start_at_different_numbers_are_said(tmp_path, caplog, start, level):
    """A 1-based frame column in the query CSV against a 0-based one in the reference moved every true match by
    one frame with no line; now a warning (1 against 0), a note for other starts, nothing when both agree."""
    from types import SimpleNamespace

    from seqnet.pipelines.ground_truth import both_positions

    names = [f"f{i}.png" for i in range(8)]
    files = []
    for side, first in (("ref", 0), ("qry", start)):
        files.append(tmp_path / f"{side}.csv")
        files[-1].write_text("name,frame\n" + "".join(f"{n},{first + i}\n" for i, n in enumerate(names)))
    images = (SimpleNamespace(names=names), SimpleNamespace(names=names))
    with caplog.at_level(logging.INFO, logger="seqnet"):
        both_positions(SimpleNamespace(ground_truth="csv", positions_format="csv"), images, (tmp_path, tmp_path),
                       tuple(files))
    said = [r for r in caplog.records if "start at" in r.getMessage()]
    assert [r.levelno for r in said] == ([] if level is None else [level])
    if start == 1:
        assert "the reference frames (" in said[0].getMessage() and "at 1: one file numbered from 1?" in \
            said[0].getMessage()


def test_a_split_without_a_match_is_said_once_and_not_blamed_on_numbering(caplog):
    """A split none of whose queries has a match is left to data.sanity's one line (it was said twice, once as
    'Recall@K is over those 0 only'); a split with few matches of files numbered alike is not told they number
    their frames differently (its queries start mid-route, the files do not)."""
    import numpy as np

    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.pipelines.ground_truth import _check_splits

    d = np.random.default_rng(0).standard_normal((30, 8)).astype(np.float32)
    ref = Traverse(d, np.arange(30.0)[:, None], name="reference")
    q_pos = np.r_[np.arange(20.0), np.arange(120.0, 130.0)]
    qry = Traverse(d, q_pos[:, None], name="query")
    splits = {"val": {"reference": (0, 30), "query": (0, 20)}, "test": {"reference": (0, 30), "query": (20, 30)},
              "few": {"reference": (0, 30), "query": (15, 30)}}
    ds = Dataset(ref, qry, radius=1.0, position_unit="frames", splits=splits, name="far")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        _check_splits(ds)
    said = [r.getMessage() for r in caplog.records]
    assert not any("split test" in s for s in said), said
    (few,) = [s for s in said if "split few" in s]
    assert "number their frames differently" not in few and "check the split's ranges" in few, few


def test_a_radius_below_the_reference_spacing_is_named_first(caplog):
    """Reference every 10 m, queries 4.5 m along, radius 4: the few-matches line names the radius against the
    reference's spacing (not swapped columns or units) and the usual radius."""
    ref = np.stack([500000 + 10.0 * np.arange(300), 7000000 + 30 * np.sin(np.arange(300) / 40)], axis=1)
    qry = ref + [4.5, 0.0] + np.random.default_rng(3).normal(0, 1, ref.shape)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        line = check_true_matches(dataset(ref, qry, 4.0))
    assert line.startswith("ds: only ") and "the radius is 4 metres, at most half the reference's frame spacing (10 " \
        "metres between neighbouring frames, median): the queries lie between its frames, out of a radius this small " \
        "(hint: a radius of at least the spacing is usual, e.g. --radius 10 or more)" in line
    assert "swapped" not in line and "another unit" not in line
