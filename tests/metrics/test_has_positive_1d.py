"""Positions along a route (1-D) find their nearest reference without scipy, as the KD-tree does."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.metrics.recall import has_positive

POS = st.lists(st.integers(-30, 30).map(lambda x: x / 4), min_size=1, max_size=40)


@settings(max_examples=100, deadline=None)
@given(POS, POS, st.sampled_from([0.25, 0.5, 1.0, 3.0]))
def test_one_dimensional_positions_agree_with_the_kd_tree(q, r, radius):
    q_pos, r_pos = np.array(q)[:, None], np.array(r)[:, None]
    want = (np.abs(q_pos - r_pos.T) <= radius).any(1)  # every pair (naive)
    np.testing.assert_array_equal(has_positive(q_pos, r_pos, radius), want)
    two = has_positive(np.c_[q_pos, np.zeros_like(q_pos)], np.c_[r_pos, np.zeros_like(r_pos)], radius)  # KD-tree
    np.testing.assert_array_equal(two, want)
