"""Explicit positives that look shifted (seqnet.metrics.shift): the offsets against a naive loop, and the
threshold that fires on 1-based positives but not on correct ones."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.metrics.shift import SHIFT_MIN, shifted_offset, top1_offsets


def naive_offsets(top1, lists):
    """For each query with positives, in order: top-1 minus its nearest positive (ties: the negative offset)."""
    out = []
    for t, pos in zip(top1, lists, strict=True):
        if not pos or t < 0:
            continue
        best = None
        for p in pos:
            d = t - p
            if best is None or abs(d) < abs(best) or (abs(d) == abs(best) and d < best):
                best = d
        out.append(best)
    return np.array(out, np.int64)


@pytest.mark.parametrize("seed", range(6))
def test_offsets_equal_a_naive_loop(seed):
    rng = np.random.default_rng(seed)
    m, n = 12, 9
    lists = [sorted(set(rng.integers(0, n, rng.integers(0, 4)).tolist())) for _ in range(m)]
    top1 = rng.integers(-1, n, m)
    q = np.array([i for i, ps in enumerate(lists) for _ in ps], np.int64)
    r = np.array([p for ps in lists for p in ps], np.int64)
    assert top1_offsets(top1, q, r).tolist() == naive_offsets(top1.tolist(), lists).tolist()


def test_a_tie_takes_the_negative_offset_and_no_positive_is_left_out():
    # query 0: top-1 3 is as far from positive 2 (+1) as from 4 (-1): -1; query 1 lists none
    assert top1_offsets(np.array([3, 5]), np.array([0, 0]), np.array([2, 4])).tolist() == [-1]


def route(n: int, seed: int, hit: float = 0.3, near: float = 0.1):
    """Top-1s of ``n`` queries whose true reference is query i: ``hit`` of them right, ``near`` one frame off on
    either side (symmetric), the rest anywhere."""
    rng = np.random.default_rng(seed)
    u = rng.random(n)
    top1 = np.where(u < hit, np.arange(n), rng.integers(0, n, n))
    side = np.where(rng.random(n) < 0.5, -1, 1)
    top1 = np.where((u >= hit) & (u < hit + near), np.clip(np.arange(n) + side, 0, n - 1), top1)
    return top1


@pytest.mark.parametrize("seed", range(5))
def test_one_based_positives_are_found_and_correct_ones_are_not(seed):
    n = 200
    top1 = route(n, seed)
    q = np.arange(n)
    assert shifted_offset(top1_offsets(top1, q, q)) is None  # correct 0-based positives: no warning
    assert shifted_offset(top1_offsets(top1, q[:-1], q[:-1] + 1)) == -1  # 1-based: every positive one after
    assert shifted_offset(top1_offsets(top1, q[3:], q[:-3])) == 3  # listed three before the true one


def test_poor_but_correct_answers_do_not_fire():
    n = 300
    rng = np.random.default_rng(7)
    top1 = rng.integers(0, n, n)  # R@1 near 0: errors anywhere, no cluster
    q = np.arange(n)
    assert shifted_offset(top1_offsets(top1, q, q)) is None
    near_misses = np.clip(q + rng.choice([-1, 1], n), 0, n - 1)  # every answer one frame off, either side
    assert shifted_offset(top1_offsets(near_misses, q, q)) is None


def test_too_few_top1s_at_the_offset_do_not_fire():
    q = np.arange(SHIFT_MIN - 1)
    assert shifted_offset(top1_offsets(q - 1, q, q)) is None
    q = np.arange(SHIFT_MIN)
    assert shifted_offset(top1_offsets(q + 10, q, q + 11)) == -1
    assert shifted_offset(np.zeros(0, np.int64)) is None
