"""The public ``seqnet.knn`` (:mod:`seqnet.search.api`): lists taken, rows checked for unit norm or normalised."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

import seqnet
from seqnet.core.errors import ConfigError
from seqnet.search.api import knn
from seqnet.search.knn import knn as exact_knn


def unit(x):
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def rescaled(rng, n=40, d=16):
    base = unit(rng.standard_normal((n, d)).astype(np.float32))
    return base, base * rng.uniform(0.3, 3, (n, 1)).astype(np.float32)


def test_seqnet_knn_is_the_checked_one():
    assert seqnet.knn is knn


def test_lists_of_rows_are_taken(rng):
    """Lists gave AttributeError: 'list' object has no attribute 'dtype'."""
    q, r = rng.standard_normal((5, 8)).astype(np.float32), rng.standard_normal((9, 8)).astype(np.float32)
    s, i = knn(q.tolist(), r.tolist(), 3, normalize=False)
    s0, i0 = exact_knn(q, r, 3)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_allclose(s, s0, rtol=1e-6)


@pytest.fixture
def unsaid(monkeypatch):
    """A process in which no warn_once line was said yet (another test may have said the same one)."""
    import seqnet.core.log

    monkeypatch.setattr(seqnet.core.log, "_SAID", set())


def test_rows_far_from_unit_norm_are_said_once_naming_row_and_norm(rng, caplog, unsaid):
    """Non-unit rows ranked otherwise than evaluate() silently (R@1 0.17 against 0.37 on rescaled Nordland rows);
    a loop over query batches said the line again on every call."""
    _, q = rescaled(rng)
    r, _ = rescaled(rng)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        for batch in range(0, 40, 10):
            knn(q[batch:batch + 10], r, 3)
    lines = [rec.getMessage() for rec in caplog.records if rec.levelno == logging.WARNING]
    assert len(lines) == 1
    norm = np.linalg.norm(q[0])
    assert f"knn: query row 0 has L2 norm {norm:.4g}, not 1" in lines[0] and "normalize=True" in lines[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        knn(r, q, 3)  # non-unit reference rows: the same advice, said once a process
        seqnet.seqmatch(r, q, 3)  # another function: its own line
    assert [rec.getMessage()[:26] for rec in caplog.records] == ["seqmatch: reference row 0 "]


@pytest.mark.parametrize("normalize", [True, False])
def test_unit_rows_and_explicit_choices_are_silent(rng, caplog, normalize):
    q, qs = rescaled(rng)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        knn(q, q, 2)  # unit rows: no line
        knn(qs, qs, 2, normalize=normalize)
        knn(q.astype(np.float16), q.astype(np.float16), 2)  # float16 rounding of unit rows
        knn(torch.from_numpy(q), torch.from_numpy(q), 2)
    assert not caplog.records


def test_normalize_ranks_as_the_normalised_rows_do(rng):
    qu, qs = rescaled(rng)
    ru, rs = rescaled(rng, 50)
    s, i = knn(qs, rs, 5, normalize=True)
    s0, i0 = exact_knn(qu, ru, 5)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_allclose(s, s0, atol=1e-5)
    naive = np.argsort(np.linalg.norm(qu[:, None] - ru[None], axis=2), axis=1, kind="stable")[:, :5]
    np.testing.assert_array_equal(i, naive)


def test_normalize_must_be_a_bool_or_none(rng):
    with pytest.raises(ConfigError, match="normalize"):
        knn(np.eye(3, dtype=np.float32), np.eye(3, dtype=np.float32), 1, normalize="yes")


def test_all_zero_rows_are_said_once_naming_the_row(rng, caplog, unsaid):
    """An all-zero query row (a failed descriptor) was ranked without a word: arbitrary ties at 0.99999994,
    while Traverse refuses the same rows."""
    r = unit(rng.standard_normal((50, 8)).astype(np.float32))
    q = unit(r + 0.05 * rng.standard_normal((50, 8)).astype(np.float32))
    q[[3, 7]] = 0
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        for normalize in (None, True, False):
            s, i = knn(q, r, 3, normalize=normalize)
        seqnet.seqmatch(q, r, 3, normalize=True)
    lines = [rec.getMessage() for rec in caplog.records]
    assert len(lines) == 2, lines  # once per function
    assert lines[0].startswith("knn: query row 3 is all zeros (2 such rows of 50); a zero descriptor matches "
                               "nothing") and "Traverse" in lines[0]
    assert lines[1].startswith("seqmatch: query row 3 is all zeros")
    naive = np.argsort(np.linalg.norm(q[:, None] - r[None], axis=2), axis=1, kind="stable")[:, :3]
    np.testing.assert_array_equal(np.delete(i, [3, 7], 0), np.delete(naive, [3, 7], 0))  # the rest is unchanged


@pytest.mark.parametrize("normalize", [None, True, False])
def test_nan_rows_are_named_not_told_to_normalise(rng, normalize):
    """NaN with normalize=True was told 'hint: L2-normalise them'."""
    q = unit(rng.standard_normal((20, 8)).astype(np.float32))
    q[5, 2] = np.nan
    with pytest.raises(ConfigError, match=r"knn: reference row 5 holds NaN or inf.*drop that row") as err:
        knn(q[:3], q, 2, normalize=normalize)
    assert "L2-normalise" not in str(err.value)


def test_cosine_is_refused_before_any_row_warning_with_the_ip_hint(rng, caplog, unsaid):
    """metric='cosine' logged the unit-norm WARNING before it was refused."""
    _, q = rescaled(rng)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        with pytest.raises(ConfigError, match=r"metric 'cosine'.*metric='ip' with normalize=True"):
            knn(q, q, 2, metric="cosine")
        with pytest.raises(ConfigError, match="k must be an integer"):
            knn(q, q, 0)
    assert not caplog.records


def test_numpy_bools_are_taken_as_normalize(rng):
    """normalize=np.True_ (e.g. from an array of flags) was refused."""
    qu, qs = rescaled(rng)
    for flag, rows in ((np.True_, qu), (np.False_, qs)):
        s, i = knn(qs, qs, 3, normalize=flag)
        naive = np.argsort(np.linalg.norm(rows[:, None] - rows[None], axis=2), axis=1, kind="stable")[:, :3]
        np.testing.assert_array_equal(i, naive)
