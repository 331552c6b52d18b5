"""The SeqNet model's tap-major weight layout (``pack_taps``, the localiser's): same values as the default layout
and as the literal convolution, for one window and for batches, in float32 and half precision, through a
checkpoint's state dict."""

from __future__ import annotations

import pytest
import torch

from seqnet.sequence.model import SeqNet


@pytest.mark.parametrize(("seq_len", "w"), [(5, 5), (10, 5), (5, 3), (2, 2), (1, 1)])
def test_packed_taps_give_the_same_descriptors(seq_len, w):
    torch.manual_seed(0)
    m = SeqNet(48, 24, seq_len, w)
    x = torch.randn(4, seq_len, 48)
    flat, one, conv = m(x), m(x[:1]), m.forward_conv(x)
    weight = m.conv.weight.detach().clone()
    assert m.pack_taps() is m and m.packed == (w > 1)
    torch.testing.assert_close(m.conv.weight.detach(), weight, rtol=0, atol=0)  # the values, another layout
    torch.testing.assert_close(m(x), flat, rtol=0, atol=1e-6)
    torch.testing.assert_close(m(x[:1]), one, rtol=0, atol=1e-6)
    torch.testing.assert_close(m(x), conv, rtol=0, atol=1e-6)
    if w > 1:
        assert m.conv.weight.permute(2, 0, 1).is_contiguous() and m.conv.weight.requires_grad
    fresh = SeqNet(48, 24, seq_len, w)  # a checkpoint of a packed model loads into the default layout
    fresh.load_state_dict(m.state_dict())
    assert not fresh.packed
    torch.testing.assert_close(fresh(x), flat, rtol=0, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_packing_survives_half_precision(dtype):
    torch.manual_seed(1)
    m = SeqNet(64, 32, 5, 5)
    x = torch.randn(1, 5, 64)
    half = SeqNet(64, 32, 5, 5)
    half.load_state_dict(m.state_dict())
    half.to(dtype)
    packed = SeqNet(64, 32, 5, 5)
    packed.load_state_dict(m.state_dict())
    packed.to(dtype).pack_taps()
    assert packed.packed and packed.conv.weight.dtype == dtype
    assert packed.pack_taps().to(dtype).packed  # casting a packed model keeps its layout
    tol = 2e-3 if dtype == torch.float16 else 2e-2
    torch.testing.assert_close(packed(x), half(x), rtol=0, atol=tol)
    torch.testing.assert_close(packed(x), m(x), rtol=0, atol=tol)
