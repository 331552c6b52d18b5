"""Calibrated confidence thresholds: against a naive loop, and the promise held in simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import binom

from seqnet.core.errors import ConfigError
from seqnet.metrics.calibration import (
    accepted,
    apply_threshold,
    calibrate,
    check_target,
    clopper_pearson,
    min_queries,
    start_count,
)


def naive_calibrate(conf, correct, target, risk):
    """The fixed sequence, one threshold at a time: the binomial test of each distinct confidence, high to low,
    from the start count on; the lowest threshold before the first failure."""
    m = len(conf)
    if m < min_queries(target, risk):
        return None
    start, best = start_count(m, target, risk), None
    tested = False
    for t in sorted(set(conf.tolist()), reverse=True):
        acc = conf >= t
        n, k = int(acc.sum()), int(correct[acc].sum())
        if n < start and t != min(conf):
            continue
        tested = True
        # H_t rejected when P(Bin(n, target) >= k) <= risk (the Clopper-Pearson lower bound reaches the target)
        if binom.sf(k - 1, n, target) > risk + 1e-12:
            break
        best = t
    assert tested
    return best


def test_min_queries_closed_form():
    for target, risk in ((0.99, 0.05), (0.95, 0.1), (0.9, 0.01)):
        assert min_queries(target, risk) == math.ceil(math.log(risk) / math.log(target))
    assert min_queries(0.99, 0.05) == 299
    n1 = min_queries(0.99, 0.05, errors=1)
    assert clopper_pearson(n1 - 1, n1, 0.05) >= 0.99 > clopper_pearson(n1 - 2, n1 - 1, 0.05)


def test_clopper_pearson_matches_binomial_tail():
    for k, n in ((0, 10), (3, 10), (10, 10), (95, 100)):
        lo, hi = clopper_pearson(k, n, 0.05), clopper_pearson(k, n, 0.05, "upper")
        assert lo <= k / n <= hi
        if k > 0:
            assert binom.sf(k - 1, n, lo) == pytest.approx(0.05, abs=1e-6)
        if k < n:
            assert binom.cdf(k, n, hi) == pytest.approx(0.05, abs=1e-6)
    assert clopper_pearson(0, 0, 0.05) == 0.0 and clopper_pearson(0, 0, 0.05, "upper") == 1.0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(300, 900), st.sampled_from([0.8, 0.9, 0.95]),
       st.sampled_from([0.05, 0.1]), st.booleans())
def test_calibrate_matches_naive_loop(seed, m, target, risk, ties):
    rng = np.random.default_rng(seed)
    conf = rng.random(m)
    if ties:
        conf = np.round(conf, 1)
    correct = rng.random(m) < 0.75 + 0.25 * conf
    cal = calibrate(conf, correct, target, risk)
    want = naive_calibrate(conf, correct, target, risk)
    assert cal.threshold == want
    if want is not None:
        acc = conf >= want
        assert (cal.accepted, cal.correct) == (int(acc.sum()), int(correct[acc].sum()))
        assert cal.lower_bound >= target


def _true_precision(t: float, a: float) -> float:
    """Confidence ~ U(0, 1), P(correct | c) = 1 − 0.3·exp(−a·c): the precision of accepting c ≥ t, exactly."""
    return 1 - 0.3 * (math.exp(-a * t) - math.exp(-a)) / (a * (1 - t))


@settings(max_examples=3, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([3.0, 5.0, 10.0]), st.sampled_from([0.9, 0.95]))
def test_promise_holds_in_simulation(seed, a, target):
    """Drawn many times from one distribution, the calibrated threshold's true precision is below the target
    in at most ``risk`` of the draws (plus the binomial noise of 120 draws)."""
    rng = np.random.default_rng(seed)
    risk, draws, violations = 0.05, 120, 0
    for _ in range(draws):
        conf = rng.random(600)
        correct = rng.random(600) < 1 - 0.3 * np.exp(-a * conf)
        cal = calibrate(conf, correct, target, risk)
        violations += cal.threshold is not None and _true_precision(cal.threshold, a) < target
    assert violations <= binom.ppf(0.999, draws, risk)


def test_declines_when_too_few_and_says_why():
    cal = calibrate(np.linspace(0, 1, 100), np.ones(100, bool), 0.99)
    assert cal.threshold is None and cal.needed == 299 and "needs at least 299" in cal.reason
    out = apply_threshold(cal, np.ones(5), np.ones(5, bool))
    assert out["accepted"] == 0 and out["precision"] is None and out["target_met"] is None
    conf = np.linspace(1, 0, 400)
    bad = np.ones(400, bool)
    bad[:3] = False  # the three most confident are wrong: the first test fails
    cal = calibrate(conf, bad, 0.99)
    assert cal.threshold is None and "no threshold passes" in cal.reason


def test_apply_reports_precision_and_interval():
    conf = np.linspace(1, 0, 1000)
    correct = conf > 0.2
    cal = calibrate(conf, correct, 0.95)
    assert cal.threshold is not None and cal.threshold <= 0.3
    out = apply_threshold(cal, conf, correct, np.ones(1000, bool))
    lo, hi = out["precision_interval"]
    assert lo <= out["precision"] <= hi and out["target_met"]
    assert out["accepted"] == int(accepted(cal, conf).sum())
    assert out["recall"] == pytest.approx(out["correct"] / 1000, abs=1e-4)


@pytest.mark.parametrize("target,risk", [(1.0, 0.05), (0.9, 0.0), (0.9, True), ("0.9", 0.1)])
def test_bad_target_or_risk_refused(target, risk):
    with pytest.raises(ConfigError):
        calibrate(np.ones(3), np.ones(3, bool), target, risk)


@pytest.mark.parametrize("risk,meant", [(0.95, "0.05"), (0.999, "0.001"), (0.9, "0.1")])
def test_a_confidence_level_given_as_the_risk_is_refused(risk, meant):
    """``--risk 0.95`` (a confidence level where the risk is meant) would promise a precision that fails 95% of
    the time: refused, naming the risk meant."""
    with pytest.raises(ConfigError, match=rf"did you mean --risk {meant}\?"):
        calibrate(np.ones(3), np.ones(3, bool), 0.9, risk)


def test_a_risk_up_to_one_half_is_accepted():
    for risk in (0.05, 0.2, 0.5):
        assert check_target(0.9, risk) == (0.9, risk)


def test_one_calibration_query_is_said_in_the_singular():
    cal = calibrate(np.ones(1), np.ones(1, bool), 0.9, 0.05)
    assert cal.reason.startswith("1 calibration query; promising"), cal.reason
