"""ExactIndex: the one-product path of a stream's frame equals the blocked search."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import ConfigError


@pytest.mark.parametrize("metric", ["l2", "ip"])
def test_a_few_rows_against_a_kept_reference_rank_as_the_blocks_do(metric):
    """The one-product path of a stream's frame (kept reference, scores that fit one block) equals the blocked
    search, ties (repeated reference rows) by the lower index included."""
    from seqnet.search.knn import ExactIndex

    rng = np.random.default_rng(3)
    ref = rng.standard_normal((500, 16)).astype(np.float32)
    ref[300:310] = ref[5]  # ties
    q = np.concatenate([ref[5:6], rng.standard_normal((2, 16)).astype(np.float32)])
    blocked = ExactIndex(ref, "cpu", col_block=64, keep=False)
    kept = ExactIndex(ref, "cpu", col_block=64, resident=True)
    assert len(kept.blocks) > 1
    for rows in (q[:1], q):
        a, b = blocked.search(rows, 15, metric), kept.search(rows, 15, metric)
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_allclose(a[0], b[0], rtol=1e-6, atol=1e-6)
    with pytest.raises(ConfigError, match="not finite"):
        kept.search(np.full((1, 16), np.inf, np.float32), 3)
