"""The CUDA paths, run where a GPU is present (``pytest -m cuda``; benchmarks/gpu_check.sh): each gives
on the GPU what it gives on the CPU (rankings equal, scores within float32 rounding)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.localizer import replay
from seqnet.localize.track import LocalizeConfig, dataset_localizer
from seqnet.search.knn import knn
from seqnet.sequence.descriptors import SeqNet

pytestmark = pytest.mark.cuda
METHODS = ("single", "seqnet", "raw+seqmatch", "s1+vseqmatch", "raw+graph", "hvpr", "hvpr-fused")


@pytest.fixture(scope="module")
def world():
    ds = make_synthetic(places=150, dim=16, seed=4).split("test")
    torch.manual_seed(0)
    models = {"seqnet": SeqNet(16, 12, 4, 2).eval(), "s1": SeqNet(16, 12, 1, 1).eval()}
    for m in models.values():
        m.provenance = ds.reference.provenance
    return ds, models


def test_knn_on_the_gpu_equals_the_cpu(rng):
    q, r = rng.standard_normal((300, 64)).astype(np.float32), rng.standard_normal((5000, 64)).astype(np.float32)
    cpu, gpu = knn(q, r, 10, device="cpu"), knn(q, r, 10, device="cuda")
    np.testing.assert_array_equal(cpu[1], gpu[1])
    np.testing.assert_allclose(cpu[0], gpu[0], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("window", ["centred", "causal"])
def test_evaluation_on_the_gpu_equals_the_cpu(world, window):
    ds, models = world
    conf = EvalConfig(methods=METHODS, window=window, ks=(1, 5))
    cpu = evaluate(ds, conf.replace(device="cpu"), {k: v.cpu() for k, v in models.items()})
    gpu = evaluate(ds, conf.replace(device="cuda"), models)
    for m in METHODS:
        assert cpu.results["methods"][m]["recall@1"] == pytest.approx(gpu.results["methods"][m]["recall@1"]), m
        np.testing.assert_array_equal(cpu.retrieved[m][:, :1], gpu.retrieved[m][:, :1], err_msg=m)


def test_localize_on_the_gpu_equals_causal_evaluation_on_the_gpu(world):
    ds, models = world
    ev = evaluate(ds, EvalConfig(methods=("hvpr",), window="causal", ks=(5,), top_k=5, device="cuda"), models)
    loc = dataset_localizer(ds, models, LocalizeConfig(method="hvpr", k=5, top_k=5, device="cuda"))
    full = [e for e in replay(loc, ds.query) if e.full_window]
    np.testing.assert_array_equal(np.stack([e.ranked for e in full])[:, 0], ev.retrieved["hvpr"][:, 0])
