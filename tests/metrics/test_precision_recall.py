"""Confidence and precision-recall against naive definitions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.metrics.precision_recall import pr_summary, precision_recall, ratio_confidence


def test_ratio_confidence_vs_loop(rng):
    m, k, r = 30, 6, 40
    r_pos = np.sort(rng.uniform(0, 100, r))[:, None]
    ranked = np.stack([rng.permutation(r)[:k] for _ in range(m)])
    scores = np.sort(rng.uniform(0.1, 2.0, (m, k)), axis=1)
    scores[0, 3:] = np.inf  # not scored: ignored
    got = ratio_confidence(scores, ranked, r_pos, radius=5.0)
    for i in range(m):
        top = r_pos[ranked[i, 0], 0]
        others = [scores[i, j] for j in range(k)
                  if abs(r_pos[ranked[i, j], 0] - top) > 5.0 and np.isfinite(scores[i, j])]
        last = max(scores[i, j] for j in range(k) if np.isfinite(scores[i, j]))  # no other place: a lower bound
        want = max(0.0, 1.0 - scores[i, 0] / (min(others) if others else last))
        assert got[i] == pytest.approx(want)


def test_confidence_edge_cases():
    r_pos = np.array([[0.0], [1.0], [50.0]])
    # the same place only (hunt 5 F5: 1.0, so --k 2 gave wrong answers full confidence): bounded by the last score
    assert ratio_confidence(np.array([[1.0, 2.0]]), np.array([[0, 1]]), r_pos, 5.0)[0] == 0.5
    assert ratio_confidence(np.array([[1.0, np.inf]]), np.array([[0, 2]]), r_pos, 5.0)[0] == 0.0  # one scored
    assert ratio_confidence(np.array([[1.0]]), np.array([[0]]), r_pos, 5.0)[0] == 0.0
    assert ratio_confidence(np.array([[1.0, 1.0]]), np.array([[0, 2]]), r_pos, 5.0)[0] == 0.0  # tie with another
    assert ratio_confidence(np.array([[0.0, 0.0]]), np.array([[0, 2]]), r_pos, 5.0)[0] == 0.0
    assert ratio_confidence(np.zeros((2, 0)), np.zeros((2, 0), int), r_pos, 5.0).tolist() == [0.0, 0.0]


@given(st.lists(st.tuples(st.floats(0, 1), st.booleans(), st.booleans()), min_size=1, max_size=30))
@settings(max_examples=80, deadline=None)
def test_precision_recall_vs_loop(rows):
    conf = np.array([r[0] for r in rows])
    has = np.array([r[2] or r[1] for r in rows])
    correct = np.array([r[1] for r in rows])
    p, rec, thr = precision_recall(conf, correct, has)
    assert (np.diff(thr) < 0).all() and (np.diff(rec) >= 0).all()
    for pi, ri, t in zip(p, rec, thr, strict=True):
        accepted = conf >= t
        tp = int((accepted & correct).sum())
        assert pi == pytest.approx(tp / accepted.sum())
        assert ri == pytest.approx(tp / max(has.sum(), 1))


def test_pr_summary():
    p, r, _ = precision_recall(np.array([0.9, 0.8, 0.7, 0.1]), np.array([1, 1, 0, 1], bool), np.ones(4, bool))
    s = pr_summary(p, r)
    assert s["recall@100p"] == pytest.approx(0.5)
    assert s["auc"] == pytest.approx(1.0 * 0.25 + 1.0 * 0.25 + (2 / 3) * 0 + 0.75 * 0.25)
    perfect = pr_summary(*precision_recall(np.arange(5.0), np.ones(5, bool), np.ones(5, bool))[:2])
    assert perfect == {"auc": 1.0, "recall@100p": 1.0}


def test_the_threshold_for_a_precision_is_the_lowest_that_reaches_it(rng):
    from seqnet.metrics.precision_recall import thresholds_for

    for _ in range(20):
        conf = rng.random(60).round(2)
        correct = rng.random(60) < 0.7
        has = correct | (rng.random(60) < 0.5)
        p, r, t = precision_recall(conf, correct, has)
        got = thresholds_for(p, r, t, (0.8, 0.95, 1.0))
        for target, entry in got.items():
            ok = [x for x in np.unique(conf) if correct[conf >= x].mean() >= float(target)]  # naive: every cut
            if not ok:
                assert entry is None
                continue
            low = min(ok)
            assert entry["confidence"] == pytest.approx(low)
            assert entry["recall"] == pytest.approx(correct[conf >= low].sum() / has.sum(), abs=1e-4)


def test_soft_matches_are_neither_true_nor_false_positives_in_pr():
    """VPR_Tutorial's createPR sets S[GTsoft & ~GThard] to the minimum: a soft-only match is skipped, the next
    retrieved reference is the top-1 of the PR curve; Recall@K counts the hard positives only."""
    from seqnet.data.positives import Positives
    from seqnet.eval.results import method_results
    from seqnet.metrics.recall import GroundTruth

    hard = Positives.from_lists([[2], [7], [4]])
    soft = Positives.from_lists([[1, 2], [7], [3, 4]])
    truth = GroundTruth(np.zeros((3, 1)), np.arange(10.0)[:, None], 0.5, Positives(hard.indptr, hard.indices,
                                                                                      soft=soft))
    ranked = np.array([[1, 2, 5], [7, 0, 1], [3, 9, 4]])  # query 0: soft then hard; query 2: soft then wrong
    scores = np.array([[0.1, 0.2, 0.9], [0.1, 0.8, 0.9], [0.1, 0.3, 0.5]])
    kept, s = truth.without_soft(ranked, scores)
    assert kept.tolist() == [[2, 5, -1], [7, 0, 1], [9, 4, -1]]
    assert s[0].tolist() == [0.2, 0.9, np.inf]
    entry, conf = method_results(scores, ranked, truth, ks=(1, 3))
    assert entry["recall@1"] == pytest.approx(1 / 3) and entry["recall@3"] == 1.0  # hard positives only
    # PR: query 0's top-1 is 2 (correct), query 1's 7 (correct), query 2's 9 (wrong): 2 of 3 accepted are right
    curve = entry["pr_curve"]
    assert curve["precision"][-1] == pytest.approx(2 / 3, abs=1e-4) and curve["recall"][-1] == pytest.approx(
        2 / 3, abs=1e-4)
    plain, _ = method_results(scores, ranked, GroundTruth(np.zeros((3, 1)), np.arange(10.0)[:, None], 0.5, hard),
                              ks=(1,))
    assert plain["pr_curve"]["precision"][-1] == pytest.approx(1 / 3, abs=1e-4)  # without soft: 1 is a FP


@pytest.mark.parametrize("transform", ["distance", "negated", "similarity-as-negated", "scaled", "shifted-negative"])
def test_confidence_is_defined_for_any_sign_and_scale(transform):
    """Queries whose top-1 is right have a large margin to the next place, the wrong ones none: whatever the
    sign and scale of the scores, accepting by confidence reaches 100 % precision up to the recall of R@1, and
    the area under the curve equals it (the curve is 1 until then)."""
    rng = np.random.default_rng(0)
    m, k = 200, 5
    right = rng.random(m) < 0.51
    best = np.where(right, 0.1, 0.8) + 0.01 * rng.random(m)
    other = np.where(right, 0.9, 0.81) + 0.01 * rng.random(m)
    d = np.column_stack([best, other, other + 0.05, other + 0.06, other + 0.07])  # ascending: lower is better
    scores = {"distance": d, "negated": d - 2.0, "similarity-as-negated": -(1.0 - d), "scaled": 1e6 * d,
              "shifted-negative": d - 0.5}[transform]
    ranked = np.tile(np.arange(k) * 10, (m, 1))  # every retrieved item another place (positions 10 apart)
    conf = ratio_confidence(scores, ranked, np.arange(100.0)[:, None], radius=1.0)
    precision, recall, _ = precision_recall(conf, right, np.ones(m, bool))
    summary = pr_summary(precision, recall)
    assert summary["recall@100p"] == pytest.approx(right.mean())
    assert summary["auc"] == pytest.approx(right.mean())
    assert (conf >= 0).all() and (conf <= 1).all()


def test_confidence_of_distances_is_the_ratio_test():
    scores = np.array([[0.2, 0.8], [0.5, 0.5], [0.0, 0.0], [0.3, 0.6]])
    ranked = np.array([[0, 5], [0, 5], [0, 5], [0, 5]])
    conf = ratio_confidence(scores, ranked, np.arange(10.0)[:, None], radius=1.0)
    np.testing.assert_allclose(conf, [1 - 0.2 / 0.8, 0.0, 0.0, 1 - 0.3 / 0.6])
