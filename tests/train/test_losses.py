"""The batched triplet loss equals the original per-triplet loop (value, gradients, counts)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from seqnet.core.errors import ConfigError
from seqnet.matching.seqmatch import seqmatch
from seqnet.sequence.model import SeqNet
from seqnet.train.losses import (
    LOSSES,
    PAIRWISE_EPS,
    batch_triplet_loss,
    describe_pair,
    graph_pad,
    triplet_loss,
    velocity_pad,
)


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


# --- the seqmatch loss (SeqMatchNet-style): margin loss on SeqMatch scores of S_1 windows ---


def _naive_seqmatch_loss(model, q_win, p_win, n_wins, margin):
    """A literal loop: S_1 of every frame, SeqMatch score Σ_t ‖S1(q_t) − S1(r_t)‖, hinge per negative, mean."""
    def s1(x):
        y = model.conv.weight[:, :, 0] @ x + model.conv.bias
        return y / torch.sqrt((y * y).sum())

    def score(a, b):
        total = 0.0
        for t in range(a.shape[0]):
            diff = s1(a[t]) - s1(b[t]) + PAIRWISE_EPS
            total = total + torch.sqrt((diff * diff).sum())
        return total

    hinges = []
    for i in range(q_win.shape[0]):
        for n in n_wins[i]:
            hinges.append(torch.clamp(score(q_win[i], p_win[i]) - score(q_win[i], n) + margin, min=0.0))
    return sum(hinges) / len(hinges)


def _windows(seed=0, b=3, k=2, length=4, d=5, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, length, d, generator=g, dtype=dtype), torch.randn(b, length, d, generator=g, dtype=dtype),
            torch.randn(b, k, length, d, generator=g, dtype=dtype))


def _seqmatch_loss(model, q_win, p_win, n_wins, margin):
    loss = LOSSES["seqmatch"]
    b, k = n_wins.shape[:2]
    emb = loss.describe(model, torch.cat([q_win, p_win, n_wins.reshape(b * k, *n_wins.shape[2:])]))
    anchor = torch.arange(b).repeat_interleave(k)
    return triplet_loss(emb[:b], emb[b : 2 * b], emb[2 * b :], anchor, margin, distance=loss.pair)


@pytest.mark.parametrize("margin", [0.5, 3.0])
def test_seqmatch_loss_equals_a_naive_loop(margin):
    torch.manual_seed(0)
    model = SeqNet(5, 4, 1, 1).double()
    q_win, p_win, n_wins = _windows(dtype=torch.float64)
    out = _seqmatch_loss(model, q_win, p_win, n_wins, margin)
    ref = _naive_seqmatch_loss(model, q_win, p_win, n_wins, margin)
    torch.testing.assert_close(out.loss, ref, rtol=1e-7, atol=1e-7)
    assert 0 < out.loss.item() and out.triplets == 6
    grads = torch.autograd.grad(out.loss, list(model.parameters()))
    ref_grads = torch.autograd.grad(ref, list(model.parameters()))
    for a, b in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)
    # the score is SeqMatch's (matching.seqmatch on the S_1 outputs of the two windows)
    with torch.no_grad():
        qd, pd = model(q_win[0][:, None]), model(p_win[0][:, None])
    expected = float(seqmatch(qd.numpy(), pd.numpy(), q_win.shape[1])[0, 0])
    assert LOSSES["seqmatch"].pair(qd[None], pd[None]).item() == pytest.approx(expected, abs=1e-4)


def test_seqmatch_mining_scores_equal_pairwise_scores():
    g = torch.Generator().manual_seed(1)
    q, r = torch.randn(4, 3, 6, generator=g), torch.randn(7, 3, 6, generator=g)
    cross = LOSSES["seqmatch"].cross(q, r)
    naive = torch.tensor([[sum(float((q[i, t] - r[j, t]).norm()) for t in range(3)) for j in range(7)]
                          for i in range(4)])
    torch.testing.assert_close(cross, naive, rtol=1e-4, atol=1e-4)


def test_seqmatch_loss_gradcheck_float64():
    """The gradient of the whole loss (S_1 of every frame, L2 norm, SeqMatch scores, hinges) with respect to
    S_1's weights and the input windows, checked against finite differences in float64."""
    q_win, p_win, n_wins = _windows(seed=2, b=2, k=2, length=3, d=4, dtype=torch.float64)
    model = SeqNet(4, 3, 1, 1).double()
    b, k = n_wins.shape[:2]

    def loss_of(weight, bias, q, p, n):
        def s1(x):
            return torch.func.functional_call(model, {"conv.weight": weight, "conv.bias": bias}, (x,))

        return _seqmatch_loss(s1, q, p, n, 2.0).loss

    inputs = tuple(t.detach().clone().requires_grad_() for t in (model.conv.weight, model.conv.bias, q_win, p_win,
                                                                n_wins))
    assert loss_of(*inputs).item() > 0  # some hinges are active: the check covers the loss, not a zero
    assert torch.autograd.gradcheck(loss_of, inputs, eps=1e-6, atol=1e-6)


def test_framewise_describe_of_an_empty_share():
    """A rank with no query of a distributed batch describes zero windows: [0, L, D'], not an error."""
    out = LOSSES["seqmatch"].describe(SeqNet(5, 4, 1, 1), torch.zeros(0, 3, 5))
    assert out.shape == (0, 3, 4)


# --- the velocity-robust loss (vseqmatch): reference windows widened, min over the matcher's trajectories -------------

def _naive_vscore(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``min_v Σ_t ‖q_t − r_{pad + p + R(v (t − p))}‖`` written out, q ``[L, D]``, r ``[L + 2·pad, D]``."""
    from seqnet.matching.velocity import DEFAULT_VELOCITIES, round_half_away

    n, pad = q.shape[0], (r.shape[0] - q.shape[0]) // 2
    p = n // 2
    scores = [sum(F.pairwise_distance(q[t][None], r[pad + p + round_half_away(v * (t - p))][None], eps=1e-6)[0]
                  for t in range(n)) for v in DEFAULT_VELOCITIES]
    return torch.stack(scores).min()


def _vwindows(seed=0, b=3, k=2, length=5, d=4, dtype=torch.float64):
    pad = velocity_pad(length)
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, length, d, generator=g, dtype=dtype),
            torch.randn(b, length + 2 * pad, d, generator=g, dtype=dtype),
            torch.randn(b, k, length + 2 * pad, d, generator=g, dtype=dtype))


def _vseqmatch_loss(model, q_win, p_win, n_wins, margin):
    loss = LOSSES["vseqmatch"]
    b, k = n_wins.shape[:2]
    q, r = describe_pair(loss, model, q_win, torch.cat([p_win, n_wins.reshape(b * k, *n_wins.shape[2:])]))
    return triplet_loss(q, r[:b], r[b:], torch.arange(b).repeat_interleave(k), margin, distance=loss.pair)


def test_velocity_pad_covers_every_trajectory():
    from seqnet.matching.velocity import DEFAULT_VELOCITIES, trajectories

    assert [velocity_pad(n) for n in (1, 2, 3, 5, 10)] == [0, 1, 1, 2, 5]  # slope 2 about the centre
    for n in (1, 2, 3, 4, 5, 10):
        offs = np.array(trajectories(DEFAULT_VELOCITIES, n, "centre")) + velocity_pad(n)
        assert offs.min() >= 0 and offs.max() < n + 2 * velocity_pad(n)


@pytest.mark.parametrize("margin", [0.5, 3.0])
def test_vseqmatch_loss_equals_a_naive_loop(margin):
    torch.manual_seed(0)
    model = SeqNet(4, 3, 1, 1).double()
    q_win, p_win, n_wins = _vwindows()
    out = _vseqmatch_loss(model, q_win, p_win, n_wins, margin)

    def s1(x):
        return model(x[:, None])

    hinges = [torch.clamp(_naive_vscore(s1(q_win[i]), s1(p_win[i])) - _naive_vscore(s1(q_win[i]), s1(n)) + margin,
                          min=0.0) for i in range(3) for n in n_wins[i]]
    ref = sum(hinges) / len(hinges)
    torch.testing.assert_close(out.loss, ref, rtol=1e-7, atol=1e-7)
    assert out.loss.item() > 0 and out.triplets == 6
    for a, b in zip(torch.autograd.grad(out.loss, list(model.parameters())),
                    torch.autograd.grad(ref, list(model.parameters())), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)


def test_vseqmatch_mining_scores_equal_pairs_and_the_matcher():
    from seqnet.matching.velocity import velocity_pairs

    g = torch.Generator().manual_seed(3)
    q = torch.randn(4, 5, 6, generator=g, dtype=torch.float64)
    r = torch.randn(7, 9, 6, generator=g, dtype=torch.float64)
    cross = LOSSES["vseqmatch"].cross(q, r)
    naive = torch.stack([torch.stack([_naive_vscore(q[i], r[j]) for j in range(7)]) for i in range(4)])
    torch.testing.assert_close(cross, naive, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(LOSSES["vseqmatch"].pair(q, r[:4]), naive.diagonal(), rtol=1e-6, atol=1e-6)
    # the matcher's score: query frames 0..4 against a reference traverse holding r[j]'s 9 frames (item start 2)
    m = velocity_pairs(q[1], r[5], 5, torch.tensor([0]), torch.tensor([[2]]))
    assert m.item() == pytest.approx(naive[1, 5].item(), abs=1e-4)
    with pytest.raises(ConfigError, match="must have 9 frames"):
        LOSSES["vseqmatch"].cross(q, r[:, :7])


def _gradcheck_through_s1(loss_fn, windows) -> None:
    """``torch.autograd.gradcheck`` of ``loss_fn(s1, q, p, n)`` w.r.t. S_1's weights and the windows (float64)."""
    model = SeqNet(windows[0].shape[-1], 3, 1, 1).double()

    def loss_of(weight, bias, q, p, n):
        def s1(x):
            return torch.func.functional_call(model, {"conv.weight": weight, "conv.bias": bias}, (x,))

        return loss_fn(s1, q, p, n, 2.0).loss

    inputs = tuple(t.detach().clone().requires_grad_() for t in (model.conv.weight, model.conv.bias, *windows))
    assert loss_of(*inputs).item() > 0  # some hinges are active: the check covers the loss, not a zero
    assert torch.autograd.gradcheck(loss_of, inputs, eps=1e-6, atol=1e-6)


def test_vseqmatch_loss_gradcheck_float64():
    _gradcheck_through_s1(_vseqmatch_loss, _vwindows(seed=2, b=2, k=2, length=3, d=4))


def test_describe_pair_is_one_forward_and_refuses_wider_windows_for_whole_window_losses():
    calls = []
    model = SeqNet(5, 4, 1, 1)

    def counted(x):
        calls.append(x.shape)
        return model(x)

    q_win, r_win = torch.randn(2, 3, 5), torch.randn(4, 5, 5)
    q, r = describe_pair(LOSSES["vseqmatch"], counted, q_win, r_win)
    assert q.shape == (2, 3, 4) and r.shape == (4, 5, 4) and calls == [(26, 1, 5)]
    torch.testing.assert_close(r[1], model(r_win[1][:, None]))  # frame by frame: S_1 of each frame
    torch.testing.assert_close(q[0], model(q_win[0][:, None]))
    with pytest.raises(ConfigError, match="framewise"):
        describe_pair(LOSSES["triplet"], model, torch.randn(2, 3, 5), torch.randn(4, 5, 5))


# --- the graph loss: the GISM-style path cost, its dynamic program under autograd --------------------------------

def _naive_graph_score(q: torch.Tensor, r: torch.Tensor, fan_out: int = 2) -> torch.Tensor:
    """Every path with steps 0..fan_out through the centre frame of ``r`` at step L // 2, its cost summed."""
    import itertools

    n, pad = q.shape[0], (r.shape[0] - q.shape[0]) // 2
    p, costs = n // 2, []
    for steps in itertools.product(range(fan_out + 1), repeat=n - 1):
        j = [0]
        for s in steps:
            j.append(j[-1] + s)
        j = [x - j[p] + pad + p for x in j]  # through the centre frame at the pivot step
        if min(j) >= 0 and max(j) < r.shape[0]:
            costs.append(sum(F.pairwise_distance(q[t][None], r[j[t]][None], eps=1e-6)[0] for t in range(n)))
    return torch.stack(costs).min()


def _gwindows(seed=0, b=3, k=2, length=5, d=4):
    pad = graph_pad(length)
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, length, d, generator=g, dtype=torch.float64),
            torch.randn(b, length + 2 * pad, d, generator=g, dtype=torch.float64),
            torch.randn(b, k, length + 2 * pad, d, generator=g, dtype=torch.float64))


def _graph_loss(model, q_win, p_win, n_wins, margin):
    loss = LOSSES["graph"]
    b, k = n_wins.shape[:2]
    q, r = describe_pair(loss, model, q_win, torch.cat([p_win, n_wins.reshape(b * k, *n_wins.shape[2:])]))
    return triplet_loss(q, r[:b], r[b:], torch.arange(b).repeat_interleave(k), margin, distance=loss.pair)


@pytest.mark.parametrize("length", [2, 4, 5])
def test_graph_scores_equal_every_path_and_the_matcher(length):
    from seqnet.matching.graph import graph_pairs

    q, r, _ = _gwindows(seed=length, b=4, length=length, d=6)
    r = torch.cat([r, r.flip(0)])  # 8 reference windows
    naive = torch.stack([torch.stack([_naive_graph_score(q[i], r[j]) for j in range(8)]) for i in range(4)])
    torch.testing.assert_close(LOSSES["graph"].cross(q, r), naive, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(LOSSES["graph"].pair(q, r[:4]), naive.diagonal(), rtol=1e-6, atol=1e-6)
    pad = graph_pad(length)  # the matcher on a reference traverse of the wide window's frames, item start pad
    m = graph_pairs(q[2], r[5], length, torch.tensor([0]), torch.tensor([[pad]]))
    assert m.item() == pytest.approx(naive[2, 5].item(), abs=1e-5)
    with pytest.raises(ConfigError, match="must have"):
        LOSSES["graph"].cross(q, r[:, 1:])


def test_graph_loss_equals_a_naive_loop_and_gradcheck_float64():
    torch.manual_seed(0)
    model = SeqNet(4, 3, 1, 1).double()
    q_win, p_win, n_wins = _gwindows()
    out = _graph_loss(model, q_win, p_win, n_wins, 3.0)

    def s1(x):
        return model(x[:, None])

    hinges = [torch.clamp(_naive_graph_score(s1(q_win[i]), s1(p_win[i])) - _naive_graph_score(s1(q_win[i]), s1(n))
                          + 3.0, min=0.0) for i in range(3) for n in n_wins[i]]
    ref = sum(hinges) / len(hinges)
    torch.testing.assert_close(out.loss, ref, rtol=1e-7, atol=1e-7)
    assert out.loss.item() > 0
    for a, b in zip(torch.autograd.grad(out.loss, list(model.parameters())),
                    torch.autograd.grad(ref, list(model.parameters())), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)
    _gradcheck_through_s1(_graph_loss, _gwindows(seed=2, b=2, k=2, length=3))
