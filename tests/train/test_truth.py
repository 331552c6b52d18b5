"""Explicit positives on traverses that are not index-aligned: negatives are measured from the positives."""

from __future__ import annotations

import numpy as np
import torch

from seqnet.data.positives import Positives
from seqnet.data.traverse import Dataset, Traverse
from seqnet.train.config import MiningConfig
from seqnet.train.source import split_windows, triplet_source
from seqnet.train.truth import near_listed, pair_masks, positive_keys, queries_with_pairs

N_REF, N_Q, OFFSET, NEG_R = 60, 30, 20, 3.0


def _offset_positives(lists=None) -> tuple[np.ndarray, np.ndarray, Positives]:
    """Frame-index positions of both traverses (not comparable) and positives query i <-> reference 20 + i."""
    q_pos, r_pos = np.arange(N_Q, dtype=np.float64)[:, None], np.arange(N_REF, dtype=np.float64)[:, None]
    return q_pos, r_pos, Positives.from_lists(lists or [[OFFSET + i] for i in range(N_Q)])


def _naive_negatives(lists, r_pos: np.ndarray, neg_radius: float) -> np.ndarray:
    out = np.zeros((len(lists), len(r_pos)), dtype=bool)
    for q, listed in enumerate(lists):
        for r in range(len(r_pos)):
            out[q, r] = all(np.linalg.norm(r_pos[r] - r_pos[p]) > neg_radius for p in listed)
    return out


def test_offset_positives_negatives_are_far_from_every_positive():
    """Query 0's positive is reference 20: 17..23 are not negatives, references 0..4 (near query 0's index) are."""
    lists = [[OFFSET + i] for i in range(N_Q)]
    lists[3] = [10, 40]  # two positives far apart: the neighbours of both are excluded
    q_pos, r_pos, pos = _offset_positives(lists)
    p_mask, n_mask = pair_masks(torch.as_tensor(q_pos), torch.as_tensor(r_pos), 1.0, NEG_R,
                                positive_keys(pos, N_REF), torch.arange(N_Q))
    assert p_mask[0].nonzero().ravel().tolist() == [20]
    assert not n_mask[0, 17:24].any() and n_mask[0, :5].all() and n_mask[0, 16] and n_mask[0, 24]
    np.testing.assert_array_equal(n_mask.numpy(), _naive_negatives(lists, r_pos, NEG_R))
    assert queries_with_pairs(q_pos, r_pos, 1.0, NEG_R, pos).all()


def test_near_listed_blocks_match_one_block():
    rng = np.random.default_rng(0)
    r_pos = torch.as_tensor(rng.uniform(0, 50, (40, 2)))
    listed = torch.as_tensor(rng.random((7, 40)) < 0.1)
    whole = near_listed(listed, r_pos, 6.0)
    np.testing.assert_array_equal(near_listed(listed, r_pos, 6.0, block_elems=1).numpy(), whole.numpy())
    d = torch.cdist(r_pos, r_pos)
    naive = torch.stack([(d[row.nonzero().ravel()] <= 6.0).any(dim=0) for row in listed])
    np.testing.assert_array_equal(whole.numpy(), naive.numpy())


def test_split_windows_mines_offset_positives_from_reference_positions():
    """A dataset with other counts and an offset: the training source's masks follow the positives."""
    q_pos, r_pos, pos = _offset_positives()
    rng = np.random.default_rng(1)
    ds = Dataset(Traverse(rng.normal(size=(N_REF, 4)).astype(np.float32), r_pos, name="reference"),
                 Traverse(rng.normal(size=(N_Q, 4)).astype(np.float32), q_pos, name="query"),
                 radius=1.0, positives=pos)
    conf = MiningConfig(pos_radius=1.0, neg_radius=NEG_R)
    assert len(split_windows(ds, 3, "centred", conf).q_idx) == N_Q - 2  # the two ends lack a full window
    src = triplet_source(ds, 3, "centred", conf, torch.device("cpu"))
    p_mask, n_mask = pair_masks(src.q_pos, src.r_pos, 1.0, NEG_R, src.pos_keys, torch.arange(src.n_queries))
    r_frames, q_frames = src.r_idx[:, 1].numpy(), src.q_idx[:, 1].numpy()
    for i in range(src.n_queries):
        true = OFFSET + q_frames[i]
        assert r_frames[p_mask[i].numpy()].tolist() == [true]
        np.testing.assert_array_equal(n_mask[i].numpy(), np.abs(r_frames - true) > NEG_R)


def test_key_mask_matches_isin_on_shuffled_rows():
    from seqnet.train.truth import key_mask

    rng = np.random.default_rng(3)
    lists = [sorted(set(rng.integers(0, 25, rng.integers(0, 6)).tolist())) for _ in range(40)]
    keys, rows = positive_keys(Positives.from_lists(lists), 25), torch.as_tensor(rng.permutation(40)[:17])
    wanted = rows[:, None] * 25 + torch.arange(25)[None, :]
    np.testing.assert_array_equal(key_mask(keys, rows, 25).numpy(), torch.isin(wanted, keys).numpy())
