"""What recall_at_k is given that says the user meant something else (:mod:`seqnet.metrics.inputs`)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.metrics.recall import recall_at_k

N = 60


def frames():
    return np.arange(N, dtype=np.float64)


def ranked(rng, k=5):
    return np.stack([rng.permutation(N)[:k] for _ in range(N)])


def test_distances_passed_as_indices_are_refused_with_the_knn_hint(rng):
    """knn's (scores, indices) unpacked the wrong way round were truncated to indices: R@1 0.010 silently."""
    scores = np.sort(rng.uniform(0.9, 1.3, (N, 5)), axis=1).astype(np.float32)
    with pytest.raises(ConfigError, match=r"non-integers \(0\.9.*knn returns \(scores, indices\)"):
        recall_at_k(scores, frames(), frames(), 1)


@pytest.mark.parametrize("given", [np.eye(N, 2, dtype=bool), np.eye(N, dtype=bool), np.ones((N, 1), bool)])
def test_booleans_passed_as_indices_are_refused(given):
    """A bool hit or ground-truth matrix passed as retrieved was read as indices 0/1: R@1 0.0 with no error."""
    with pytest.raises(ConfigError, match=r"retrieved holds booleans \(60 x \d+\), not reference indices.*hint: "
                                          r"knn returns \(scores, indices\)"):
        recall_at_k(given, frames(), frames(), 0.5, ks=(1,))


def test_whole_float_indices_are_taken_as_the_integers(rng):
    idx = ranked(rng)
    assert recall_at_k(idx.astype(np.float64), frames(), frames(), 1) == recall_at_k(idx, frames(), frames(), 1)


def test_nan_position_is_a_config_error_naming_the_row(rng):
    """A NaN position ended in scipy's ValueError ('x' must be finite)."""
    pos = np.c_[np.zeros(N), np.arange(N) * 10.0]
    bad = pos.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ConfigError, match=r"query positions hold NaN or inf \(first at row 5\)"):
        recall_at_k(ranked(rng), bad, pos, 10)
    with pytest.raises(ConfigError, match=r"reference positions hold NaN"):
        recall_at_k(ranked(rng), pos, bad, 10)


def test_transposed_positions_are_named_not_retrieved(rng):
    """[2, N] positions made the message blame retrieved ('retrieved must be [2, K]')."""
    pos = np.c_[np.zeros(N), np.arange(N) * 10.0]
    with pytest.raises(ConfigError, match=r"query positions look transposed: shape \(2, 60\).*pos\.T"):
        recall_at_k(ranked(rng), pos.T, pos.T, 10)


@pytest.mark.parametrize("pos, hint", [
    (np.c_[63.43 + np.arange(N) * 10 / 111320, np.full(N, 10.39)], "degrees"),  # lat/lon, 10 m per frame
    (np.c_[np.full(N, 431.2), 7034.5 + np.arange(N) * 0.01], "radius as large as the route"),  # UTM km, radius m
])
def test_trivial_truth_is_said_as_seqnet_eval_says_it(rng, caplog, pos, hint):
    """Degrees or km positions with a radius of 25 m gave R@1 1.000 without a word."""
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        out = recall_at_k(ranked(rng), pos, pos, 25)
    assert out["recall@1"] == 1.0
    assert "recall_at_k: the median query has 100% of the 60 references" in caplog.text and hint in caplog.text


def test_correct_inputs_stay_silent(rng, caplog):
    pos = np.c_[np.zeros(N), np.arange(N) * 10.0]
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        a = recall_at_k(ranked(rng), pos, pos, 25, ks=(1, 5))
        b = recall_at_k(ranked(rng), frames(), frames(), 1, ks=(1, 5))
    assert not caplog.records and 0 <= a["recall@1"] <= 1 and 0 <= b["recall@1"] <= 1


def test_whole_number_scores_passed_as_indices_are_refused(rng):
    """knn's ip scores of binary descriptors (19, 17, 16, 15, 15) were read as indices: R@1 0.0125, not 0.7625."""
    from seqnet.search.api import knn

    r = (rng.random((80, 32)) > 0.5).astype(np.float32)
    q = np.where(rng.random(r.shape) < 0.1, 1 - r, r)
    pos = np.arange(80.0)
    scores, idx = knn(q, r, 5, metric="ip", normalize=False)
    with pytest.raises(ConfigError, match=r"retrieved row \d+ \(.*\) repeats a value.*knn returns \(scores, indices"):
        recall_at_k(scores, pos, pos, 0.5, (1, 5))
    got = recall_at_k(idx.astype(np.float64), pos, pos, 0.5, (1, 5))
    naive = np.mean([abs(idx[m, 0] - m) <= 0.5 for m in range(80)])  # a naive loop over the queries
    assert got["recall@1"] == pytest.approx(naive) and naive > 0.5


def test_whole_float_rankings_padded_with_minus_one_are_taken(rng):
    """The repeat rule never refuses a ranking: only -1 (none) may repeat in a row."""
    idx = ranked(rng).astype(np.float64)
    idx[::3, 2:] = -1
    got = recall_at_k(idx, frames(), frames(), 1, ks=(1, 5))
    naive = np.mean([any(r >= 0 and abs(r - m) <= 1 for r in idx[m]) for m in range(N)])
    assert got["recall@5"] == pytest.approx(naive)
