"""Sequence confidence (neighbouring answers that agree) against a naive loop, and the map step it assumes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.metrics.consistency import STEPS, QueryOrder, map_step, sequence_confidence


def naive_step(q, t, seq, answered, span):
    """The step most pairs of answered queries ≤ ``span`` frames apart (one sequence) agree on within one frame
    (ties: nearest 1), refined to the median slope of the pairs near it."""
    pairs = [(t[j] - t[i], q[j] - q[i]) for i in range(len(q)) for j in range(len(q))
             if seq[i] == seq[j] and answered[i] and answered[j] and 0 < q[j] - q[i] <= span]
    if not pairs:
        return 1.0
    votes = np.array([sum(abs(dt - v * dq) <= 1.0 for dt, dq in pairs) for v in STEPS])
    best = np.flatnonzero(votes == votes.max())
    v0 = STEPS[best[np.argmin(np.abs(STEPS[best] - 1.0))]]
    near = [dt / dq for dt, dq in pairs if abs(dt - v0 * dq) <= max(1.0, abs(v0))]
    return float(np.median(near)) if near else float(v0)


def naive_pairs(q, seq, answered, span):
    return sum(1 for i in range(len(q)) for j in range(len(q))
               if seq[i] == seq[j] and answered[i] and answered[j] and 0 < q[j] - q[i] <= span)


def naive_steps(order, top):
    """Each query's step: its sequence's own (with ≥ 2 span pairs of answers), else all sequences' together."""
    seq = np.zeros(len(top), int) if order.q_seq is None else order.q_seq
    t = np.where(top >= 0, order.r_frames[top.clip(0)], 0)
    pooled = naive_step(order.q_frames, t, seq, top >= 0, order.span)
    out = np.full(len(top), pooled)
    for s in set(seq.tolist()):
        mine = seq == s
        if len(set(seq.tolist())) > 1 and naive_pairs(order.q_frames[mine], seq[mine], (top >= 0)[mine],
                                                      order.span) >= 2 * order.span:
            out[mine] = naive_step(order.q_frames[mine], t[mine], seq[mine], (top >= 0)[mine], order.span)
    return out


def naive_confidence(ratio, top, order):
    out = []
    offsets = list(range(-order.span, 0)) + ([] if order.causal else list(range(1, order.span + 1)))
    seq = np.zeros(len(top), int) if order.q_seq is None else order.q_seq
    steps = naive_steps(order, top)
    for i in range(len(top)):
        agree, step = 0, steps[i]
        for d in offsets:
            for j in range(len(top)):
                if seq[j] == seq[i] and order.q_frames[j] == order.q_frames[i] + d and top[i] >= 0 and top[j] >= 0:
                    dt = order.r_frames[top[j]] - order.r_frames[top[i]]
                    agree += abs(step) * order.span >= 1 and abs(dt - step * d) <= max(1.0, abs(step))
        out.append((agree + ratio[i]) / (len(offsets) + 1))
    return np.clip(out, 0, 1)


@st.composite
def cases(draw):
    m = draw(st.integers(0, 14))
    frames = np.array(sorted(draw(st.sets(st.integers(0, 30), min_size=m, max_size=m))), dtype=np.int64)
    seq = np.array(draw(st.lists(st.integers(0, 2), min_size=m, max_size=m)), dtype=np.int64)
    n_ref = draw(st.integers(1, 25))
    top = np.array(draw(st.lists(st.integers(-1, n_ref - 1), min_size=m, max_size=m)), dtype=np.int64)
    r_frames = np.array(sorted(draw(st.sets(st.integers(0, 60), min_size=n_ref, max_size=n_ref))), dtype=np.int64)
    ratio = np.array(draw(st.lists(st.floats(0, 1), min_size=m, max_size=m)))
    perm = np.array(draw(st.permutations(list(range(m)))), dtype=np.int64)  # any query order
    order = QueryOrder(frames[perm], r_frames, draw(st.integers(1, 4)), draw(st.booleans()),
                       seq[perm] if draw(st.booleans()) else None)
    return ratio[perm], top[perm], order


@given(cases())
@settings(max_examples=150, deadline=None)
def test_sequence_confidence_vs_loop(case):
    ratio, top, order = case
    got = sequence_confidence(ratio, top, order)
    np.testing.assert_allclose(got, naive_confidence(ratio, top, order), atol=1e-12)
    assert ((got >= 0) & (got <= 1)).all()


def test_a_route_driven_together_agrees_and_a_lone_wrong_answer_does_not():
    q = np.arange(40)
    top = q + 7  # query frame i is reference frame i + 7
    top[20] = 3  # a look-alike place far away
    ratio = np.full(40, 0.5)
    conf = sequence_confidence(ratio, top, QueryOrder(q, np.arange(60), span=5))
    assert conf[20] == pytest.approx(0.5 / 11)  # nothing agrees with it
    assert conf[10] == pytest.approx((10 + 0.5) / 11)  # all ten neighbours agree
    assert conf[19] == pytest.approx((9 + 0.5) / 11)  # the wrong one does not
    assert conf[0] == pytest.approx((5 + 0.5) / 11)  # the route's first query has neighbours on one side only
    causal = sequence_confidence(ratio, top, QueryOrder(q, np.arange(60), span=5, causal=True))
    assert causal[10] == pytest.approx((5 + 0.5) / 6) and causal[21] == pytest.approx((4 + 0.5) / 6)


@pytest.mark.parametrize(("step", "noise"), [(1.0, 0.0), (-1.0, 0.3), (2.0, 0.5), (0.5, 0.2), (3.0, 0.6)])
def test_the_map_step_survives_a_majority_of_wrong_answers(step, noise, rng):
    q = np.arange(300)
    t = np.round(step * q + (600 if step < 0 else 0)).astype(np.int64)
    wrong = rng.random(300) < noise
    t[wrong] = rng.integers(0, 1000, wrong.sum())
    got = map_step(q, t, np.zeros(300, np.int64), np.ones(300, bool), 5)
    assert got == pytest.approx(step)


def test_sequences_and_unanswered_queries():
    q = np.arange(10)
    top = np.arange(10)
    seq = np.array([0] * 5 + [1] * 5)  # two sequences: no neighbour across them
    conf = sequence_confidence(np.zeros(10), top, QueryOrder(q, np.arange(10), span=5, q_seq=seq))
    assert conf.tolist() == pytest.approx([4 / 11] * 10)
    top[3] = -1  # no answer: agrees with nothing, and nothing agrees with it
    conf = sequence_confidence(np.zeros(10), top, QueryOrder(q, np.arange(10), span=5, q_seq=seq))
    assert conf[3] == 0.0 and conf[0] == pytest.approx(3 / 11)
    assert sequence_confidence(np.zeros(0), np.zeros(0, int), QueryOrder(q[:0], np.arange(3), span=2)).shape == (0,)
    assert map_step(q[:1], top[:1], seq[:1], np.ones(1, bool), 3) == 1.0  # no pair: the equal-sampling step


def test_a_stuck_matcher_gets_no_agreement_and_each_sequence_its_own_step():
    q = np.arange(60)
    ratio = np.linspace(0, 1, 60)
    stuck = sequence_confidence(ratio, np.full(60, 5), QueryOrder(q, np.arange(80), span=5))
    np.testing.assert_allclose(stuck, ratio / 11)  # every answer the same reference: nothing moves, no witness
    seq = np.array([0] * 30 + [1] * 30)
    top = np.r_[np.arange(30) + 10, 70 - np.arange(30)]  # the second sequence driven the other way
    conf = sequence_confidence(np.zeros(60), top, QueryOrder(q, np.arange(80), span=5, q_seq=seq))
    assert conf[15] == pytest.approx(10 / 11) and conf[45] == pytest.approx(10 / 11)
