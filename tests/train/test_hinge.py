"""The fused triplet hinge (seqnet.train.hinge) against the autograd expression it replaces."""

import pytest
import torch
import torch.nn.functional as F

from seqnet.train.hinge import triplet_hinge
from seqnet.train.losses import PAIRWISE_EPS, triplet_loss


def autograd_hinge(q, p, n, anchor, margin, denom):
    d_pos = F.pairwise_distance(q, p, eps=PAIRWISE_EPS)
    d_neg = F.pairwise_distance(q[anchor], n, eps=PAIRWISE_EPS)
    hinge = F.relu(d_pos[anchor] - d_neg + margin)
    return hinge.sum() / denom, hinge


@pytest.mark.parametrize("total", [None, 50])
def test_value_and_gradient_equal_autograd(total):
    gen = torch.Generator().manual_seed(1)
    b, t, d = 7, 30, 16
    q, p, n = (F.normalize(torch.randn(k, d, generator=gen, dtype=torch.float64), dim=1) for k in (b, b, t))
    p[0] = q[0]  # a zero distance (up to eps)
    anchor = torch.randint(0, b - 1, (t,), generator=gen)  # query b - 1 has no triplet
    denom = t if total is None else total
    leaves = [x.clone().requires_grad_() for x in (q, p, n)]
    loss, hinge = triplet_hinge(*leaves, anchor, 0.4, denom, PAIRWISE_EPS)
    grads = torch.autograd.grad(loss, leaves)
    ref_leaves = [x.clone().requires_grad_() for x in (q, p, n)]
    ref, ref_hinge = autograd_hinge(*ref_leaves, anchor, 0.4, denom)
    ref_grads = torch.autograd.grad(ref, ref_leaves)
    assert loss.item() == ref.item() and torch.equal(hinge, ref_hinge.detach())
    assert 0 < int((hinge > 0).sum()) < t  # active and inactive triplets both present
    for g, r in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(g, r, rtol=1e-12, atol=1e-12)
    assert not hinge.requires_grad


def test_triplet_loss_uses_it_with_the_same_numbers():
    gen = torch.Generator().manual_seed(2)
    q, p, n = (torch.randn(k, 8, generator=gen) for k in (3, 3, 9))
    anchor = torch.tensor([0, 0, 1, 1, 1, 2, 2, 2, 2])
    out = triplet_loss(q, p, n, anchor, 2.0)
    ref, ref_hinge = autograd_hinge(q, p, n, anchor, 2.0, 9)
    assert out.loss.item() == ref.item() and out.triplets == 9 and out.active == int((ref_hinge > 0).sum())
