"""Explicit positives whose layout could be read two ways: a CSV header naming its columns in either order,
a pairs-like ``.npy``, a transposed dense matrix; each is read as it says, or refused, never guessed."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import DatasetError
from seqnet.data.positives import read_positives

PAIRS = [(0, 3), (1, 4), (2, 5), (2, 6)]  # (query, reference)


def _rows(p) -> list[list[int]]:
    return [p.of(i).tolist() for i in range(len(p))]


@pytest.mark.parametrize("header, swap", [
    ("query,reference", False), ("reference,query", True), ("Reference ; Query", True), ("db,q", True),
    ("database_index,query_index", True), ("q,ref", False), ("\ufeffquery_id,ref_id", False),
])
def test_csv_header_names_the_columns_in_either_order(tmp_path, header, swap):
    lines = [f"{r},{q}" if swap else f"{q},{r}" for q, r in PAIRS]
    (tmp_path / "p.csv").write_text("\n".join([header, *lines]) + "\n", encoding="utf-8")
    assert _rows(read_positives(tmp_path / "p.csv")) == [[3], [4], [5, 6]]


@pytest.mark.parametrize("header", ["a,b", "query,query", "image,reference", "query,reference,score", "frame,db"])
def test_csv_header_it_does_not_understand_is_refused(tmp_path, header):
    (tmp_path / "p.csv").write_text(f"{header}\n0,3\n")
    with pytest.raises(DatasetError, match=r"p\.csv, line 1: header .* does not name a query and a reference "
                                           r"column; expected 'query,reference' or 'reference,query'"):
        read_positives(tmp_path / "p.csv")


@pytest.mark.parametrize("sep", ["\t", " ", "  "])
def test_csv_pairs_separated_by_tabs_or_spaces(tmp_path, sep):
    """L2: a tab- or space-separated file was read as a header ('header '0\\t3' does not name ...'), now as pairs,
    with or without a header."""
    (tmp_path / "p.csv").write_text("\n".join(f"{q}{sep}{r}" for q, r in PAIRS) + "\n")
    assert _rows(read_positives(tmp_path / "p.csv")) == [[3], [4], [5, 6]]
    (tmp_path / "h.csv").write_text("\n".join([f"reference{sep}query", *(f"{r}{sep}{q}" for q, r in PAIRS)]) + "\n")
    assert _rows(read_positives(tmp_path / "h.csv")) == [[3], [4], [5, 6]]


@pytest.mark.parametrize("text, match", [
    ("0|3\n1|4\n", r"p\.csv, line 1: '0\|3' is neither two integers separated by ',', ';', a tab or spaces, nor a "
                   "header naming"),
    ("0\t3\n1,4\n", r"p\.csv, line 2: expected 'query,reference' \(two integers\), got '1,4' \(fields separated by "
                      r"tabs, as on the first line\)"),
])
def test_csv_data_line_with_another_separator_is_not_called_a_header(tmp_path, text, match):
    (tmp_path / "p.csv").write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_positives(tmp_path / "p.csv")


def test_csv_pairs_imply_the_queries_after_the_last_pair(tmp_path):
    """Pairs list no query without a match: the rows after the last pair are added, empty, for the traverse."""
    (tmp_path / "p.csv").write_text("reference,query\n3,0\n5,2\n")
    p = read_positives(tmp_path / "p.csv").check(5, 10)
    assert _rows(p) == [[3], [], [5], [], []]
    with pytest.raises(DatasetError, match="3 rows of positives for 2 query images"):
        read_positives(tmp_path / "p.csv").check(2, 10)


def test_npy_that_may_be_pairs_is_refused(tmp_path):
    np.save(tmp_path / "p.npy", np.array(PAIRS[:3]))
    with pytest.raises(DatasetError, match=r"may be \(query, reference\) pairs or two reference indices per query"):
        read_positives(tmp_path / "p.npy")
    np.save(tmp_path / "rows.npy", np.array([[3, 4], [4, -1], [5, 6]]))  # rows of references: unambiguous
    assert _rows(read_positives(tmp_path / "rows.npy")) == [[3, 4], [4], [5, 6]]


def test_transposed_dense_matrix_is_named(tmp_path):
    gt = np.zeros((6, 4), bool)  # [N_ref, N_query]: the wrong way round
    gt[np.arange(4), np.arange(4)] = True
    np.save(tmp_path / "gt.npy", gt)
    with pytest.raises(DatasetError, match=r"6 rows of positives for 4 query images .*transposed\? the matrix is "
                                           r"\[6, 4\]; seqnet reads \[N_query, N_reference\]"):
        read_positives(tmp_path / "gt.npy").check(4, 6)


def _naive_matrix_rows(grid) -> list[list[int]]:
    """The positives a 0/1 matrix means, by a loop: the columns of each row that hold a 1."""
    return [[j for j, v in enumerate(row) if v] for row in grid]


@pytest.mark.parametrize("convert", [
    lambda g: g.astype(int).tolist(), lambda g: g.astype(bool).tolist(), lambda g: g.astype(float).tolist(),
    lambda g: [tuple(r) for r in g.astype(int)], lambda g: list(g.astype(np.uint8)),
])
def test_dataset_reads_rows_of_zeros_and_ones_as_the_matrix(convert):
    """A ground-truth matrix's ``.tolist()`` was read as lists of reference indices: every query got {0, 1}."""
    from seqnet.data.traverse import Dataset, Traverse

    rng = np.random.default_rng(0)
    grid = rng.random((12, 20)) < 0.2
    fr = np.arange(20.0)
    ds = Dataset(Traverse(np.ones((20, 4), np.float32), fr), Traverse(np.ones((12, 4), np.float32), fr[:12]),
                 radius=1.0, positives=convert(grid))
    assert _rows(ds.positives) == _naive_matrix_rows(grid)


def test_rows_of_zeros_and_ones_that_could_be_indices_are_refused_at_the_matrix_width():
    """Two references and rows [0, 1] / [1, 0]: a matrix (one positive) or indices (both); refused, not guessed."""
    from seqnet.data.positives import Positives, as_positives

    with pytest.raises(DatasetError, match=r"different positives \(hint: np.asarray\(rows, dtype=bool\)"):
        as_positives([[0, 1], [1, 0], [0, 1]], 3, 2)
    assert _rows(as_positives(np.array([[0, 1], [1, 0], [0, 1]], bool), 3, 2)) == [[1], [0], [1]]
    assert _rows(as_positives(Positives.from_lists([[0, 1], [1, 0], [0, 1]]), 3, 2)) == [[0, 1]] * 3
    assert _rows(as_positives([[0, 1], [1, 0], [0, 1]], 3, 5)) == [[0, 1]] * 3  # 5 wide: only indices fit
    assert _rows(as_positives([[0, 4], [2], []], 3, 5)) == [[0, 4], [2], []]  # index lists stay index lists


def test_zero_one_rows_elsewhere_are_a_matrix_or_refused(tmp_path):
    """A JSON 0/1 matrix and ``Positives.from_lists(matrix.tolist())`` were read as indices {0, 1}."""
    from seqnet.data.positives import Positives

    grid = np.eye(6, dtype=int)
    (tmp_path / "gt.json").write_text(str(grid.tolist()))
    assert _rows(read_positives(tmp_path / "gt.json")) == _naive_matrix_rows(grid)
    with pytest.raises(DatasetError, match=r"query 0: reference indices repeat.*0/1 \[N_query, N_reference\] matrix"):
        Positives.from_lists(grid.tolist())
    with pytest.raises(DatasetError, match=r"must be integers.*hint: give a matrix as a numpy array"):
        Positives.from_lists(grid.astype(bool).tolist())


def test_python_array_that_may_be_pairs_is_refused_with_the_python_hint():
    """An [Nq, 2] array of two references per query (first column 0..Nq-1) was refused with a hint to save a CSV
    or a JSON file; in Python the two readings are Positives.from_lists and Positives.from_pairs."""
    from seqnet.data.positives import Positives, as_positives

    n = 8
    idx = np.array([[i, min(i + 1, n - 1)] for i in range(n)])
    with pytest.raises(DatasetError, match=r"pairs or two reference indices per query.*hint: Positives\.from_lists"
                                           r"\(arr\.tolist\(\)\) .*Positives\.from_pairs\(arr\[:, 0\], arr\[:, 1\], "
                                           r"n_queries\)") as err:
        as_positives(idx, n, n)
    assert "CSV" not in str(err.value)
    naive = [sorted({int(a), int(b)}) for a, b in idx]  # two references per query, by a loop
    assert _rows(as_positives(Positives.from_lists(idx.tolist()), n, n)) == naive
    pairs = as_positives(Positives.from_pairs(idx[:, 0], idx[:, 1], n), n, n)
    assert _rows(pairs) == [[int(b)] for _, b in idx]
    shifted = idx[::-1].copy()  # first column not 0..n-1: only rows of references fit, taken as such
    assert _rows(as_positives(shifted, n, n)) == [sorted({int(a), int(b)}) for a, b in shifted]


def test_json_rows_of_zeros_and_ones_that_could_be_indices_are_refused_at_the_matrix_width(tmp_path):
    """JSON [[0, 1], [1, 0], [0, 1]] with 2 references was read as indices ({0, 1} for every query) without the
    check as_positives makes on the same Python list."""
    from seqnet.data.positives import as_positives

    rows = [[0, 1], [1, 0], [0, 1]]
    (tmp_path / "amb.json").write_text(str(rows))
    with pytest.raises(DatasetError, match=r"3 rows of 2 zeros and ones .*different positives \(hint: write a "
                                           r"matrix with true / false entries"):
        as_positives(read_positives(tmp_path / "amb.json"), 3, 2)
    naive = [sorted(set(r)) for r in rows]  # 5 references: only the index reading fits
    assert _rows(as_positives(read_positives(tmp_path / "amb.json"), 3, 5)) == naive
    (tmp_path / "bool.json").write_text("[[false, true], [true, false], [false, true]]")
    assert _rows(as_positives(read_positives(tmp_path / "bool.json"), 3, 2)) == _naive_matrix_rows(rows)
