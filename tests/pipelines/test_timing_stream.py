"""Incremental online SeqMatch equals the batch definition on causal windows."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.matching.seqmatch import seqmatch
from seqnet.pipelines.timing.stream import OnlineSeqMatch


@pytest.mark.parametrize("L", [1, 2, 4])
@pytest.mark.parametrize("reverse", [False, True])
def test_stream_equals_batch(rng, L, reverse):
    q, r = rng.standard_normal((15, 6)), rng.standard_normal((20, 6))
    full = seqmatch(q, r, L, reverse=reverse, device="cpu")  # [Nq - L + 1, Nr - L + 1]
    online = OnlineSeqMatch(r, L, reverse=reverse, device="cpu")
    for i in range(len(q)):
        row = online.step(q[i])
        if i < L - 1:
            assert row is None
        else:
            np.testing.assert_allclose(row.numpy(), full[i - L + 1], rtol=1e-9, atol=1e-9)
    assert online.n_windows == len(r) - L + 1


def test_reset_and_topk(rng):
    q, r = rng.standard_normal((6, 3)).astype(np.float32), rng.standard_normal((9, 3)).astype(np.float32)
    online = OnlineSeqMatch(torch.from_numpy(r), 3, device="cpu")
    for x in q[:3]:
        row = online.step(x)
    online.reset()
    assert online.step(q[3]) is None and online.step(q[4]) is None
    row = online.step(q[5])
    np.testing.assert_allclose(row.numpy(), seqmatch(q[3:6], r, 3, device="cpu")[0], rtol=1e-5)
    v, i = online.topk(row, 2, starts=np.array([6, 0, 3]))
    sub = row.numpy()[[6, 0, 3]]
    assert i.tolist() == np.argsort(sub, kind="stable")[:2].tolist() and np.allclose(v, np.sort(sub)[:2])


def test_errors(rng):
    r = rng.standard_normal((5, 3))
    with pytest.raises(ConfigError, match="seq_len"):
        OnlineSeqMatch(r, 6)
    online = OnlineSeqMatch(r, 2, device="cpu")
    with pytest.raises(ConfigError, match="dimension mismatch"):
        online.step(np.zeros(4))
    with pytest.raises(ConfigError, match="NaN"):
        online.step(np.array([np.nan, 0, 0]))
