"""The batched triplet loss equals the original per-triplet loop (value, gradients, counts)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from seqnet.core.errors import ConfigError
from seqnet.train.losses import batch_triplet_loss, triplet_loss


def _loop_loss(q, p, n, valid, margin):
    """The original SeqNet code: one nn.TripletMarginLoss call per (query, negative), summed, / count."""
    crit = nn.TripletMarginLoss(margin=margin, p=2, reduction="sum")
    loss, count = 0.0, 0
    for i in range(q.shape[0]):
        for k in range(n.shape[1]):
            if valid[i, k]:
                loss = loss + crit(q[i : i + 1], p[i : i + 1], n[i, k : k + 1])
                count += 1
    return loss / count, count


def _batch(seed=0, b=6, k=5, d=8):
    g = torch.Generator().manual_seed(seed)
    q = F.normalize(torch.randn(b, d, generator=g), dim=1).requires_grad_()
    p = F.normalize(torch.randn(b, d, generator=g), dim=1).requires_grad_()
    n = F.normalize(torch.randn(b, k, d, generator=g), dim=2).requires_grad_()
    valid = torch.rand(b, k, generator=g) > 0.3
    valid[0] = False  # a query without negatives
    valid[1] = True
    return q, p, n, valid


@pytest.mark.parametrize("margin", [0.1, 0.3, 1.0])
def test_batched_loss_equals_per_triplet_loop(margin):
    q, p, n, valid = _batch()
    out = batch_triplet_loss(q, p, n, margin, valid)
    grads = torch.autograd.grad(out.loss, (q, p, n))
    ref, count = _loop_loss(q, p, n, valid, margin)
    ref_grads = torch.autograd.grad(ref, (q, p, n))
    assert out.triplets == count == int(valid.sum())
    torch.testing.assert_close(out.loss, ref, rtol=1e-6, atol=1e-7)
    for a, b in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)


def test_active_counts_positive_hinges_only():
    q, p, n, valid = _batch(seed=3)
    out = batch_triplet_loss(q, p, n, 0.3, valid)
    d_pos = (q - p).norm(dim=1, keepdim=True)
    d_neg = (q[:, None] - n).norm(dim=2)
    expected = int(((d_pos - d_neg + 0.3 > 0) & valid).sum())
    assert out.active == expected
    assert out.active < out.triplets  # the random batch has both kinds
    assert torch.all(out.per_triplet[~valid] == 0)


def test_no_valid_triplet_gives_zero_loss():
    q, p, n, valid = _batch()
    out = batch_triplet_loss(q, p, n, 0.3, torch.zeros_like(valid))
    assert out.loss.item() == 0.0 and out.triplets == 0 and out.active == 0


def test_default_mask_uses_every_negative():
    q, p, n, _ = _batch()
    out = batch_triplet_loss(q, p, n, 0.3)
    ref, _ = _loop_loss(q, p, n, torch.ones(n.shape[:2], dtype=torch.bool), 0.3)
    torch.testing.assert_close(out.loss, ref)


def test_flat_triplets_equal_the_masked_batch():
    q, p, n, valid = _batch(seed=5)
    anchor = valid.nonzero()[:, 0]
    flat = triplet_loss(q, p, n[valid], anchor, 0.3)
    masked = batch_triplet_loss(q, p, n, 0.3, valid)
    torch.testing.assert_close(flat.loss, masked.loss)
    torch.testing.assert_close(flat.per_triplet, masked.per_triplet[valid])
    with pytest.raises(ConfigError):
        triplet_loss(q, p, n[valid], anchor[:-1], 0.3)


@pytest.mark.parametrize("bad", ["shape_p", "shape_n", "mask", "margin"])
def test_bad_inputs_raise_config_error(bad):
    q, p, n, valid = _batch()
    args = {"query": q, "positive": p, "negatives": n, "margin": 0.3, "valid": valid}
    if bad == "shape_p":
        args["positive"] = p[:3]
    elif bad == "shape_n":
        args["negatives"] = n[:, :, :4]
    elif bad == "mask":
        args["valid"] = valid[:, :2]
    else:
        args["margin"] = 0.0
    with pytest.raises(ConfigError):
        batch_triplet_loss(**args)
