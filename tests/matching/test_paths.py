"""The path dynamic program (matching.paths): the running minimum in place and under autograd agree."""

from __future__ import annotations

import torch

from seqnet.matching.paths import path_dp, runmin


def test_runmin_under_autograd_equals_the_in_place_one():
    x = torch.randn(3, 7, dtype=torch.float64)
    for backward in (False, True):
        for fan_out in (0, 1, 2, 9):
            y = x.clone().requires_grad_()
            out = runmin(y, fan_out, backward)
            assert out.requires_grad and torch.equal(out.detach(), runmin(x, fan_out, backward))


def test_path_dp_under_autograd_equals_the_in_place_one_and_has_a_gradient():
    d = torch.rand(5, 2, 9, dtype=torch.float64)
    fast = path_dp(lambda t: d[t], 5, 2, 2)
    x = d.clone().requires_grad_()
    slow = path_dp(lambda t: x[t], 5, 2, 2)
    assert torch.equal(fast, slow.detach())
    slow[..., 4].sum().backward()  # one path per row through the pivot column: its 5 steps get gradient 1
    assert torch.equal(x.grad.sum(dim=(0, 2)), torch.full((2,), 5.0, dtype=torch.float64))
