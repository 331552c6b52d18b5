"""Half-precision localisation (--precision): the same answers as float32, half the bytes read."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.localize.stream import index_reference
from seqnet.maps import MapConfig, build, load_map
from seqnet.search.knn import ExactIndex
from seqnet.sequence.checkpoints import load_model
from seqnet.sequence.model import SeqNet

CONF = LocalizeConfig(k=7, top_k=5, device="cpu", seq_len=4)


@pytest.mark.parametrize("precision", [torch.float16, torch.bfloat16])
def test_half_exact_search_matches_float32(rng, precision):
    ref = rng.standard_normal((300, 64)).astype(np.float32)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    q = ref[[3, 50, 299]] + 0.05 * rng.standard_normal((3, 64)).astype(np.float32)
    full, half = ExactIndex(ref), ExactIndex(ref, precision=precision)
    tol = 2e-2 if precision == torch.bfloat16 else 3e-3
    np.testing.assert_allclose(half.distances(q).numpy(), full.distances(q).numpy(), atol=tol)
    d, i = half.search(q, 5)
    assert d.dtype == np.float32 and i[:, 0].tolist() == [3, 50, 299]
    assert half.block(0, 10, half.dtype(q)).dtype == precision  # the kept copy is half precision


def test_a_half_model_reads_half_and_answers_in_float32(rng):
    torch.manual_seed(0)
    model = SeqNet(32, 16, 5, 3).eval()
    x = torch.as_tensor(rng.standard_normal((4, 5, 32)).astype(np.float32))
    with torch.no_grad():
        want = model(x)
        model.to(torch.float16)
        got = model(x)
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), want.numpy(), atol=5e-3)


@pytest.mark.parametrize("precision", ["float16", "bfloat16"])
def test_half_precision_localiser_answers_as_float32(synth_dataset, map_models, precision):
    models = {r: load_model(p) for r, p in zip(("seqnet", "s1"), map_models, strict=True)}
    test = synth_dataset.split("test")
    full = list(replay(dataset_localizer(test, {r: m for r, m in models.items()}, CONF), test.query))
    models = {r: load_model(p) for r, p in zip(("seqnet", "s1"), map_models, strict=True)}
    loc = dataset_localizer(test, models, CONF.replace(precision=precision))
    assert loc.ref.precision == getattr(torch, precision)
    assert all(m.conv.weight.dtype == getattr(torch, precision) for m in loc.models.values())
    half = list(replay(loc, test.query))
    agree = np.mean([a.ref_index == b.ref_index for a, b in zip(full, half, strict=True)])
    assert agree >= (0.97 if precision == "float16" else 0.93), agree  # bfloat16: 8 bits of mantissa, near-ties


def test_a_float16_map_is_searched_as_stored(synth_dataset, synth_dir, map_models, tmp_path):
    mp = load_map(build(MapConfig(seq_len=4, window="causal", dtype="float16"), synth_dir, tmp_path / "m",
                        map_models), "cpu")
    conf = CONF.replace(precision="float16")
    loc = conf.localizer(*index_reference(mp, conf))
    test = synth_dataset.split("test")
    assert any(e.ref_index >= 0 for e in replay(loc, test.query))
    block = mp.exact_search(mp.shortlist).block(0, 4, torch.float16)
    assert block.dtype == torch.float16 and np.shares_memory(block.numpy(), np.asarray(mp.shortlist))


def test_an_unknown_precision_is_refused():
    with pytest.raises(ConfigError, match="precision.*float32.*float16.*bfloat16"):
        LocalizeConfig(precision="int8")
