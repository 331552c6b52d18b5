"""The converters' image names: names kept beside a .npy, the route order of CSV rows matched by name,
ambiguous and missing names, sequence columns, CSV separators and byte-order marks."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.core.errors import DatasetError
from seqnet.data.convert import (
    CsvNames,
    match_names,
    read_positions_csv,
    sequence_bounds,
    traverse_from_csv,
    traverse_from_utm_names,
)
from seqnet.data.convert.csvfile import SHORT_SEQUENCE
from seqnet.data.io import load_dataset
from seqnet.data.spacing import out_of_order


def _describe_like(path, desc, names):
    """A .npy as `seqnet describe --out X.npy` writes it: the array, X.names.txt and the bound provenance."""
    from seqnet.describe.output import write_output

    write_output(path, desc.shape, [desc], names, "{}", {"id": "test-describer"})
    assert (path.parent / (path.stem + ".names.txt")).read_text().split() == names


@pytest.fixture
def described(tmp_path, rng):
    """200 frames named frame_1 .. frame_200 (not zero-padded), described in that (route) order; a reference CSV
    in route order and a query CSV sorted as text (frame_1, frame_10, frame_100, ...), as `sort` does."""
    n = 200
    names = [f"frame_{k + 1}.png" for k in range(n)]
    base = rng.standard_normal((n, 16)).astype(np.float32)
    _describe_like(tmp_path / "ref_desc.npy", base, names)
    _describe_like(tmp_path / "qry_desc.npy", base + 0.01, names)
    rows = [(nm, k) for k, nm in enumerate(names)]
    (tmp_path / "ref.csv").write_text("name,frame\n" + "".join(f"{a},{b}\n" for a, b in rows))
    (tmp_path / "qry_lex.csv").write_text("name,frame\n" + "".join(f"{a},{b}\n" for a, b in sorted(rows)))
    return tmp_path


def test_from_csv_reads_the_names_beside_a_npy_and_keeps_the_descriptors_order(described, caplog):
    """H1/M7: the names describe wrote beside the .npy pair rows by name (not by order), and the route is the
    descriptors' order, whatever the CSV's; the CSV's other order is said at default verbosity."""
    caplog.set_level(logging.INFO, logger="seqnet")
    rc = main(["dataset", "from-csv", "--ref-csv", str(described / "ref.csv"), "--ref-desc",
               str(described / "ref_desc.npy"), "--query-csv", str(described / "qry_lex.csv"), "--query-desc",
               str(described / "qry_desc.npy"), "--radius", "1", "--split", "test=100:200", "--out",
               str(described / "ds")])
    assert rc == 0
    ds = load_dataset(described / "ds")
    assert ds.query.names[:3] == ["frame_1.png", "frame_2.png", "frame_3.png"]
    np.testing.assert_array_equal(ds.query.positions[:, 0], np.arange(200))  # query frame k is at frame k
    np.testing.assert_allclose(ds.query.descriptors, ds.reference.descriptors + 0.01, rtol=1e-5, atol=1e-6)
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert not any("by order" in m for m in warned)
    order = [m for m in warned if "another order than" in m]
    assert len(order) == 1 and "qry_lex.csv" in order[0] and "follows the descriptors' order" in order[0]


def test_rows_paired_by_order_are_a_warning(tmp_path, rng, caplog):
    """Without any names, row i is descriptor i, and that is said at default verbosity (it was DEBUG)."""
    caplog.set_level(logging.WARNING, logger="seqnet")
    (tmp_path / "r.csv").write_text("name,frame\nb,0\na,1\n")
    np.save(tmp_path / "r.npy", rng.random((2, 4), dtype=np.float32))
    t, _ = traverse_from_csv(tmp_path / "r.csv", tmp_path / "r.npy", name="reference")
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "by order" in r.getMessage()]
    assert t.names == ["b", "a"] and len(said) == 1 and "--ref-names" in said[0]


def test_from_utm_names_reads_the_names_beside_a_npy_and_names_the_flag(tmp_path, rng):
    names = [f"@{500000 + 2 * i}.00@{4000000}.00@17@T@.jpg" for i in range(5)]
    desc = rng.standard_normal((5, 4)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    np.save(tmp_path / "db.npy", desc)
    with pytest.raises(DatasetError, match=r"db.npy: no image names; give a names file \(--ref-names FILE\)"):
        traverse_from_utm_names(tmp_path / "db.npy", name="reference")
    (tmp_path / "db.names.txt").write_text("\n".join(names) + "\n")
    t = traverse_from_utm_names(tmp_path / "db.npy", name="reference")
    assert t.names == names and t.positions[:, 0].tolist() == [500000, 500002, 500004, 500006, 500008]
    (tmp_path / "db.names.txt").write_text("\n".join(names[:4]) + "\n")
    with pytest.raises(DatasetError, match=r"db.names.txt: 4 names for 5 descriptors"):
        traverse_from_utm_names(tmp_path / "db.npy", name="reference")


def test_a_name_without_extension_matching_two_images_names_its_line_and_both(tmp_path):
    """M9: 'images-10040' in a CSV matches both images-10040.png and images-10040.jpg: an error naming the
    CSV line and both images (both got the row's position)."""
    (tmp_path / "q.csv").write_text("name,frame\n" + "".join(f"images-{i},{k}\n" for k, i in
                                                              enumerate(range(10000, 10060, 10))))
    names, *_ = read_positions_csv(tmp_path / "q.csv")
    images = [f"images-{i}.png" for i in range(10000, 10060, 10)] + ["images-10040.jpg"]
    with pytest.raises(DatasetError, match=r"q.csv vs the query images: the name 'images-10040' \(line 6\) matches "
                                           r"two images, 'images-10040.jpg' and 'images-10040.png'"):
        match_names(sorted(images), names, "q.csv vs the query images")
    assert match_names(images[:-1], names, "w").tolist() == list(range(6))


def test_missing_names_say_which_side_lacks_them_in_the_singular(tmp_path):
    """L3: an image without a CSV row 'has no row in' the CSV (it said 'has no descriptor'); a case-only
    difference is named."""
    (tmp_path / "r.csv").write_text("name,frame\nIMG-1.PNG,0\nIMG-2.PNG,1\n")
    names, *_ = read_positions_csv(tmp_path / "r.csv")
    with pytest.raises(DatasetError, match=r"1 of 1 image name has no row in .*r.csv \(first: 'img-3.png'; the names "
                                           r"in .*r.csv look like 'IMG-1.PNG'\); hint"):
        match_names(["img-3.png"], names, "r.csv vs the reference images")
    with pytest.raises(DatasetError, match=r"2 of 2 image names have no row .*the names differ only in case "
                                           r"\('img-1.png' and 'IMG-1.PNG'\)"):
        match_names(["img-1.png", "img-2.png"], names, "r.csv vs the reference images")
    with pytest.raises(DatasetError, match=r"2 of 2 image names have no descriptor"):
        match_names(["a", "b"], ["c", "d"], "w")


def test_two_csv_rows_matching_one_descriptor_are_refused():
    rows = CsvNames(["a/x.png", "b/x.png"], "r.csv", [2, 3])
    with pytest.raises(DatasetError, match=r"the name 'x.png' matches two rows of r.csv, 'a/x.png' \(line 2\) and "
                                           r"'b/x.png' \(line 3\)"):
        match_names(rows, ["x.png", "y.png"], "w")


def test_interleaved_or_short_sequences_are_warned_about(caplog):
    """M2: a sequence id in several runs (a camera id alternating row by row) makes one-frame sequences: said,
    naming the column; every sequence shorter than the default L: said."""
    from seqnet.sequence.windows import DEFAULT_SEQ_LEN

    assert SHORT_SEQUENCE == DEFAULT_SEQ_LEN
    caplog.set_level(logging.WARNING, logger="seqnet")
    bounds = sequence_bounds(["A" if k % 2 else "B" for k in range(200)], "q.csv (column 'sequence')")
    assert (bounds[:, 1] - bounds[:, 0] == 1).all()
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 2
    assert said[0].startswith("q.csv (column 'sequence'): sequence id 'B' occurs in 100 separate runs of rows "
                              "(2 ids of 2 do so)") and "the 200 rows form 200 sequences (median length 1)" in said[0]
    assert "every sequence is shorter than 5 frames (the longest has 1)" in said[1]
    caplog.clear()
    sequence_bounds(["A"] * 3 + ["B"] * 3, "w")  # in order, but short: one line
    assert [r.getMessage() for r in caplog.records] == ["w: every sequence is shorter than 5 frames (the longest has "
                                                        "3), the default sequence length L; sequence methods need "
                                                        "--seq-len at most 3, or longer sequences"]
    caplog.clear()
    sequence_bounds(["A"] * 10 + ["B"] * 4, "w")
    assert not caplog.records


def test_sequence_column_follows_the_descriptors_order(tmp_path, rng, caplog):
    """A CSV in another order than the descriptors: its sequence column is read in the route (descriptor)
    order, so each sequence is one run (in the CSV's order it was 100 runs)."""
    names = [f"f{k:03d}.png" for k in range(100)]
    np.save(tmp_path / "d.npy", rng.random((100, 4), dtype=np.float32))
    (tmp_path / "d.names.txt").write_text("\n".join(names) + "\n")
    order = rng.permutation(100)
    (tmp_path / "c.csv").write_text("name,frame,sequence\n" + "".join(f"{names[k]},{k},s{k // 50}\n" for k in order))
    caplog.set_level(logging.WARNING, logger="seqnet")
    t, _ = traverse_from_csv(tmp_path / "c.csv", tmp_path / "d.npy", name="query")
    assert t.names == names and t.seq_bounds.tolist() == [[0, 50]] * 50 + [[50, 100]] * 50
    assert not any("separate runs" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("text", ["\ufeffname,frame\na.png,0\nb.png,1\n", "name;frame\na.png;0\nb.png;1\n",
                                  "name\tframe\na.png\t0\nb.png\t1\n", "\ufeffName;Frame\r\na.png;0\r\nb.png;1\r\n"])
def test_positions_csv_with_a_bom_or_another_separator(tmp_path, text):
    """L1: Excel's 'CSV UTF-8' byte-order mark, ';' (a spreadsheet with decimal commas) and tabs are read."""
    (tmp_path / "p.csv").write_text(text, encoding="utf-8")
    names, pos, unit, _ = read_positions_csv(tmp_path / "p.csv")
    assert names == ["a.png", "b.png"] and pos.tolist() == [[0], [1]] and unit == "frames"


def test_space_separated_header_names_the_separators(tmp_path):
    (tmp_path / "p.csv").write_text("name frame\na.png 0\n")
    with pytest.raises(DatasetError, match=r"has no image-name column; .*fields are separated by ',', ';' or a tab, "
                                           "not spaces"):
        read_positions_csv(tmp_path / "p.csv")


def test_route_order_hint_fits_how_positions_were_paired():
    """M7: with names, rows were paired by name: the hint is about the images' order, not the pairing."""
    shuffled = np.random.default_rng(0).permutation(300).astype(float)[:, None]
    unnamed = out_of_order(shuffled, None, 1.0, "frames", "query")
    named = out_of_order(shuffled, None, 1.0, "frames", "query", named=True)
    assert "pair them by image name: --ref-names / --query-names" in unnamed
    assert "pair them by image name" not in named and "put the images in route order" in named


def test_decimal_commas_get_a_hint(tmp_path):
    (tmp_path / "p.csv").write_text("name;easting;northing\na.png;500000,5;4000000,25\n")
    with pytest.raises(DatasetError, match=r"p.csv, line 2: .*got \['500000,5', '4000000,25'\]; hint: write decimal "
                                           "points, not decimal commas"):
        read_positions_csv(tmp_path / "p.csv")


def test_names_that_differ_only_in_unicode_normalisation_match():
    """macOS file names in NFD ('o' + a combining diaeresis) against NFC names typed in a CSV matched nothing, and
    the error showed two identical-looking names; they now match (an NFC rung after exact, file name, stem)."""
    import unicodedata

    nfc = [f"Straße_Köln_{k:03d}.png" for k in range(4)]
    nfd = [unicodedata.normalize("NFD", "photos/" + n) for n in nfc]
    assert nfd[0] != "photos/" + nfc[0]
    csv = CsvNames(nfc[::-1], "pos.csv", [5, 4, 3, 2])
    assert match_names(nfd, csv, "pos.csv vs the images").tolist() == [3, 2, 1, 0]
    assert match_names(nfc, nfd, "x").tolist() == [0, 1, 2, 3]
    with pytest.raises(DatasetError, match="each also in Unicode NFC form"):
        match_names(nfd + ["Münster.png"], csv, "pos.csv vs the images")


def test_names_whose_leading_zeros_a_spreadsheet_stripped_match_by_value(tmp_path, caplog):
    """KITTI-style ``0000000000.png`` images against CSV names ``0, 1, 2`` (Excel made them numbers): matched by
    value and said; two images equal as numbers are refused as ambiguous; exact names say nothing."""
    images = [f"{k:010d}.png" for k in range(3)]
    with caplog.at_level("INFO", logger="seqnet"):
        assert match_names(images, ["2", "0", "1"], "t").tolist() == [1, 2, 0]
    assert "t: names matched as numbers ('0000000000.png' and '0'): leading zeros stripped" in caplog.text
    with pytest.raises(DatasetError, match="matches two"):
        match_names(["1"], ["01.png", "001.png"], "t")
    caplog.clear()
    with caplog.at_level("INFO", logger="seqnet"):
        assert match_names(images, images, "t").tolist() == [0, 1, 2]
    assert not caplog.records


def test_a_csv_in_cp1252_is_told_to_be_saved_as_utf8(tmp_path):
    from seqnet.data.convert import read_positions_csv

    (tmp_path / "p.csv").write_bytes("name,frame\nkøy.png,0\n".encode("cp1252"))
    with pytest.raises(DatasetError, match=r"not UTF-8 text .*; hint: text in another encoding \(Windows-1252, "
                                           r"Latin-1\)\? Save it as UTF-8"):
        read_positions_csv(tmp_path / "p.csv")
