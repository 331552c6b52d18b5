"""Mining returns only true negatives, the hardest among the sampled, and the closest positive."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.train.config import MiningConfig, check_radii
from seqnet.train.mining import (
    closest_positive,
    hardest_negatives,
    mine_batch,
    sample_negatives,
)
from seqnet.train.source import split_windows, triplet_source
from seqnet.train.truth import pair_masks, positive_keys, queries_with_pairs, radius_masks

POS_R, NEG_R = 5.0, 20.0


def _scene(seed=0, b=6, r=80, d=8):
    """UTM-like positions (large offsets) along a line, and random unit descriptors."""
    rng = np.random.default_rng(seed)
    r_pos = np.stack([500000.0 + 2.0 * np.arange(r), np.full(r, 6.0e6)], axis=1)
    q_pos = r_pos[rng.choice(r, b, replace=False)] + rng.normal(0, 1.5, (b, 2))
    g = torch.Generator().manual_seed(seed)
    q_feat = F.normalize(torch.randn(b, d, generator=g), dim=1)
    r_feat = F.normalize(torch.randn(r, d, generator=g), dim=1)
    return torch.from_numpy(q_pos), torch.from_numpy(r_pos), q_feat, r_feat


def _pos_dist(q_pos, r_pos):
    return np.linalg.norm(q_pos.numpy()[:, None, :] - r_pos.numpy()[None, :, :], axis=-1)


def test_radius_masks_match_brute_force_on_utm():
    q_pos, r_pos, _, _ = _scene()
    pos, neg = radius_masks(q_pos, r_pos, POS_R, NEG_R)
    dist = _pos_dist(q_pos, r_pos)
    np.testing.assert_array_equal(pos.numpy(), dist <= POS_R)
    np.testing.assert_array_equal(neg.numpy(), dist > NEG_R)
    assert pos.any(1).all() and neg.any(1).all()


def test_closest_positive_is_closest_in_descriptor_space():
    dist = torch.tensor([[0.5, 0.2, 0.9, 0.1], [0.3, 0.4, 0.1, 0.2]])
    mask = torch.tensor([[True, True, True, False], [False, False, False, False]])
    idx, d = closest_positive(dist, mask)
    assert idx.tolist() == [1, -1]
    assert d[0].item() == pytest.approx(0.2) and torch.isinf(d[1])


def test_hardest_negatives_match_a_loop():
    g = torch.Generator().manual_seed(1)
    dist = torch.rand(5, 40, generator=g) * 2
    cand = torch.rand(5, 40, generator=g) > 0.5
    d_pos = torch.rand(5, generator=g)
    idx, valid, _ = hardest_negatives(dist, cand, d_pos, 4, 0.3)
    for i in range(5):
        cols = [j for j in torch.argsort(dist[i]).tolist() if cand[i, j]][:4]
        expected = [j for j in cols if dist[i, j] < d_pos[i] + 0.3]
        assert idx[i][valid[i]].tolist() == expected
        assert torch.all(idx[i][~valid[i]] == -1)


def test_sample_negatives_draws_distinct_true_negatives():
    q_pos, r_pos, _, _ = _scene()
    _, neg = radius_masks(q_pos, r_pos, POS_R, NEG_R)
    s = sample_negatives(neg, 10, torch.Generator().manual_seed(0))
    assert not (s & ~neg).any()  # only negatives
    big = sample_negatives(neg.repeat(200, 1), 10, torch.Generator().manual_seed(0))
    assert abs(big.sum(1).float().mean().item() - 10) < 0.5  # 10 on average
    few = neg & (torch.arange(neg.shape[1]) < 30)  # rows with at most 10 negatives: all of them
    few[:, :] = False
    few[:, :5] = True
    assert torch.equal(sample_negatives(few, 10, torch.Generator().manual_seed(0)), few)
    s2 = sample_negatives(neg, 10, torch.Generator().manual_seed(1))
    assert not torch.equal(s, s2)  # it is random
    assert torch.equal(sample_negatives(neg, 10_000, torch.Generator()), neg)  # n_sample >= R: all


def test_mine_batch_returns_true_negatives_hardest_among_all_when_all_sampled():
    q_pos, r_pos, q_feat, r_feat = _scene(seed=2)
    pos, neg = radius_masks(q_pos, r_pos, POS_R, NEG_R)
    m = mine_batch(q_feat, r_feat, pos, neg, 10, 1000, 0.3, torch.Generator().manual_seed(0))
    dist_pos = _pos_dist(q_pos, r_pos)
    d = torch.cdist(q_feat, r_feat).numpy()
    for i in range(len(q_feat)):
        p_cols = np.flatnonzero(dist_pos[i] <= POS_R)
        assert m.positive[i].item() == p_cols[np.argmin(d[i, p_cols])]
        got = m.negatives[i][m.valid[i]].numpy()
        assert np.all(dist_pos[i, got] > NEG_R)  # only true negatives
        n_cols = np.flatnonzero(dist_pos[i] > NEG_R)
        hardest = n_cols[np.argsort(d[i, n_cols], kind="stable")][:10]
        hardest = hardest[d[i, hardest] < d[i, m.positive[i]] + 0.3]
        np.testing.assert_array_equal(got, hardest)
    assert m.valid.sum() > 0


def test_mine_batch_picks_hardest_among_the_sample():
    q_pos, r_pos, q_feat, r_feat = _scene(seed=4)
    pos, neg = radius_masks(q_pos, r_pos, POS_R, NEG_R)
    m = mine_batch(q_feat, r_feat, pos, neg, 3, 12, 5.0, torch.Generator().manual_seed(7))
    sample = sample_negatives(neg, 12, torch.Generator().manual_seed(7))  # the same draw
    d = torch.cdist(q_feat, r_feat)
    for i in range(len(q_feat)):
        cols = torch.nonzero(sample[i])[:, 0]
        expected = cols[torch.argsort(d[i, cols], stable=True)][:3]
        assert m.negatives[i].tolist() == expected.tolist()  # margin 5: every sampled one violates
    all_neg_hardest = torch.topk(d.masked_fill(~neg, 9), 3, largest=False).indices
    assert not torch.equal(m.negatives, all_neg_hardest)  # a sample of 12, not all negatives


def test_negative_cache_is_reused_but_only_true_negatives():
    q_pos, r_pos, q_feat, r_feat = _scene(seed=5, b=2)
    pos, neg = radius_masks(q_pos, r_pos, POS_R, NEG_R)
    d = torch.cdist(q_feat, r_feat).masked_fill(~neg, 9)
    hardest = d.argmin(1)
    not_neg = torch.nonzero(~neg[1])[0, 0]
    cache = torch.stack([hardest, torch.full_like(hardest, -1)], 1)
    cache[1, 1] = not_neg  # a stale non-negative must never come back
    m = mine_batch(q_feat, r_feat, pos, neg, 2, 1, 5.0, torch.Generator().manual_seed(0), cache)
    assert m.negatives[:, 0].tolist() == hardest.tolist()
    assert not_neg.item() not in m.negatives[1].tolist()


def test_queries_with_pairs_and_radii_checks():
    r_pos = np.arange(0.0, 100.0)[:, None]
    q_pos = np.array([[10.2], [200.0], [50.0]])
    np.testing.assert_array_equal(queries_with_pairs(q_pos, r_pos, 1.0, 4.0), [True, False, True])
    assert not queries_with_pairs(np.array([[50.0]]), r_pos, 1.0, 1000.0).any()  # no negative
    with pytest.raises(ConfigError, match="pos_radius"):
        check_radii(5.0, 2.0)
    with pytest.raises(ConfigError):
        check_radii(0.0, 2.0)


def test_triplet_source_windows_and_errors(synth_dataset):
    ds = synth_dataset.split("train")
    conf = MiningConfig(pos_radius=5.0, neg_radius=20.0)
    src = triplet_source(ds, 5, "centred", conf, torch.device("cpu"))
    assert src.q_idx.shape[1] == 5 and src.r_idx.shape[1] == 5
    assert torch.all(src.q_idx[:, 1:] - src.q_idx[:, :-1] == 1)
    centre = src.q_idx[:, 2].numpy()
    np.testing.assert_allclose(src.q_pos.numpy(), ds.query.positions[centre])
    with pytest.raises(DatasetError, match=r"pos_radius.*hint: .*a larger --pos-radius / a smaller --neg-radius\)"):
        triplet_source(ds, 5, "centred", MiningConfig(pos_radius=1e-9, neg_radius=1e9), torch.device("cpu"))
    with pytest.raises(DatasetError, match="train split: .*full window"):
        triplet_source(ds, 10_000, "centred", conf, torch.device("cpu"))


def test_split_windows_names_the_split_and_counts_left_out_queries(synth_dataset):
    val = synth_dataset.split("val")
    sw = split_windows(val, 3, "centred", MiningConfig(pos_radius=5.0, neg_radius=20.0), "val")
    assert len(sw.q_idx) + sw.left_out <= len(val.query) and len(sw.q_idx) > 0
    with pytest.raises(DatasetError, match="val split: no .* full window of seq_len=500"):
        split_windows(val, 500, "centred", MiningConfig(pos_radius=5.0, neg_radius=20.0), "val")
    with pytest.raises(DatasetError, match="none of .* val queries"):
        split_windows(val, 3, "centred", MiningConfig(pos_radius=1e-9, neg_radius=1e9), "val")


def test_mining_config_validates():
    with pytest.raises(ConfigError, match="n_negatives"):
        MiningConfig(pos_radius=1.0, neg_radius=2.0, n_negatives=0)
    with pytest.raises(ConfigError, match="pos_radius <= neg_radius"):
        MiningConfig(pos_radius=3.0, neg_radius=2.0)


def test_explicit_positives_decide_the_masks():
    """With explicit positives, positives are the listed pairs, negatives the references far from all of them."""
    from seqnet.data.positives import Positives

    q_pos = np.array([[0.0], [10.0], [20.0]])
    r_pos = np.arange(30.0)[:, None]
    pos = Positives.from_lists([[5], [], [20, 21]])
    keys = positive_keys(pos, len(r_pos))
    p_mask, n_mask = pair_masks(torch.as_tensor(q_pos), torch.as_tensor(r_pos), 1.0, 4.0, keys, torch.arange(3))
    assert p_mask[0].nonzero().ravel().tolist() == [5] and not p_mask[1].any()
    assert p_mask[2].nonzero().ravel().tolist() == [20, 21]
    far = torch.as_tensor([[abs(r - 5) > 4 for r in range(30)], [True] * 30,
                           [min(abs(r - 20), abs(r - 21)) > 4 for r in range(30)]])
    np.testing.assert_array_equal(n_mask.numpy(), far.numpy())  # beyond neg_radius of every positive
    assert not n_mask[0, 5]  # a listed positive is never a negative, even far away
    np.testing.assert_array_equal(queries_with_pairs(q_pos, r_pos, 1.0, 4.0, pos), [True, False, True])


def test_soft_positives_are_never_negatives():
    """VPR_Tutorial's GTsoft: a soft positive is neither a positive nor a negative in mining."""
    from seqnet.data.positives import Positives
    from seqnet.train.truth import nonnegative_keys

    q_pos, r_pos = np.array([[0.0], [10.0]]), np.arange(30.0)[:, None]
    hard = Positives.from_lists([[5], [12]])
    pos = Positives(hard.indptr, hard.indices, soft=Positives.from_lists([[5, 6, 25], [12]]))
    n = len(r_pos)
    p_mask, n_mask = pair_masks(torch.as_tensor(q_pos), torch.as_tensor(r_pos), 1.0, 4.0, positive_keys(pos, n),
                                torch.arange(2), nonnegative_keys(pos, n))
    assert p_mask[0].nonzero().ravel().tolist() == [5]  # the soft ones are not positives
    assert not n_mask[0, 25] and not n_mask[0, 6] and n_mask[0, 24] and n_mask[0, 26]  # nor negatives
    _, without = pair_masks(torch.as_tensor(q_pos), torch.as_tensor(r_pos), 1.0, 4.0, positive_keys(pos, n),
                            torch.arange(2))
    assert without[0, 25]  # without the soft set, 25 m away is a negative
    assert nonnegative_keys(hard, n) is None


def test_training_uses_explicit_positives(tmp_path):
    """A dataset whose explicit positives point elsewhere than the positions: mining follows the positives."""
    import dataclasses

    from seqnet.data.positives import Positives
    from seqnet.data.synth import make_synthetic
    from seqnet.train.config import TrainConfig

    ds = make_synthetic(places=200, dim=8, seed=2).split("train")
    n_q, n_r = len(ds.query), len(ds.reference)
    shifted = Positives.from_lists([[min(n_r - 1, i + 7)] for i in range(n_q)])
    ds = dataclasses.replace(ds, positives=shifted)
    conf = TrainConfig(seq_len=3, w=2).resolve(ds).mining
    sw = split_windows(ds, 3, "centred", conf)
    assert sw.positives is not None and len(sw.positives) == len(sw.q_idx)
    src = triplet_source(ds, 3, "centred", conf, torch.device("cpu"))
    rows = torch.arange(src.n_queries)
    p_mask, _ = pair_masks(src.q_pos, src.r_pos, conf.pos_radius, conf.neg_radius, src.pos_keys, rows)
    q_frames = src.q_idx[:, 1]  # centre frames of the query windows
    r_frames = src.r_idx[:, 1]
    for i in range(0, src.n_queries, 17):
        listed = r_frames[p_mask[i]].tolist()
        assert listed == [min(n_r - 1, int(q_frames[i]) + 7)], (i, listed)


def test_positions_in_degrees_are_named_when_no_query_has_pairs(synth_dataset):
    """Own-data hostile 52 M4: positions in degrees read as metres made train refuse with 'check the train ranges,
    or a larger --pos-radius / a smaller --neg-radius', which failed again when followed: the cause is named."""
    val = synth_dataset.split("val")

    def degrees(t):  # a route along a line of latitude, in degrees: 1e-5 degrees a metre, about
        return dataclasses.replace(t, positions=np.column_stack([10.75 + 1e-5 * t.positions[:, 0],
                                                                 np.full(len(t), 59.91)]))

    deg = {s: degrees(getattr(val, s)) for s in ("query", "reference")}
    with pytest.raises(DatasetError, match=r"none of .* val queries .*positions look like degrees") as e:
        split_windows(dataclasses.replace(val, **deg), 3, "centred", MiningConfig(pos_radius=3.0, neg_radius=12.0),
                      "val")
    assert "--pos-radius" not in str(e.value)
    with pytest.raises(DatasetError) as e:  # metres: the radius hint as before
        split_windows(val, 3, "centred", MiningConfig(pos_radius=1e-9, neg_radius=1e9), "val")
    assert "degrees" not in str(e.value) and "--pos-radius" in str(e.value)
