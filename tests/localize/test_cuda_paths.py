"""The CUDA paths, run where a GPU is present (``pytest -m cuda``; benchmarks/gpu_check.sh): each gives
on the GPU what it gives on the CPU (rankings equal, scores within float32 rounding)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.search.knn import knn
from seqnet.sequence.model import SeqNet

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


def test_training_on_the_gpu_follows_the_cpu(tmp_path):
    """One epoch on cuda and on cpu from the same seed: the same triplets, weights within float rounding."""
    from seqnet.sequence.checkpoints import read_checkpoint
    from seqnet.train import TrainConfig, train

    ds = make_synthetic(places=200, dim=8, seed=2)
    conf = TrainConfig(optimizer="adam", lr=1e-2, n_neg_sample=50, cache_refresh=40, seq_len=3, w=2, out_dims=8,
                       epochs=1)
    train(ds, conf.replace(device="cpu"), tmp_path / "cpu")
    train(ds, conf.replace(device="cuda"), tmp_path / "gpu")
    a, b = (read_checkpoint(tmp_path / d / "last.pt") for d in ("cpu", "gpu"))
    assert max(float((a["state_dict"][k] - b["state_dict"][k]).abs().max()) for k in a["state_dict"]) < 1e-3
    assert a["train_state"]["history"][0]["loss"] == pytest.approx(b["train_state"]["history"][0]["loss"], rel=1e-3)


def test_nccl_process_group_on_one_gpu():
    """NCCL initialises and reduces on this GPU (a world of one: seqnet's collectives need two GPUs to run)."""
    import os

    import torch.distributed as dist

    if not dist.is_nccl_available():
        pytest.skip("this torch build has no NCCL")
    os.environ.setdefault("MASTER_ADDR", "127.0.0.1")
    os.environ.setdefault("MASTER_PORT", "29533")
    dist.init_process_group("nccl", rank=0, world_size=1)
    try:
        x = torch.ones(4, device="cuda")
        dist.all_reduce(x)
        assert x.tolist() == [1.0] * 4
    finally:
        dist.destroy_process_group()


def test_a_map_on_the_gpu_equals_the_cpu(tmp_path):
    from seqnet.data.io import save_dataset
    from seqnet.maps import MapConfig, build, load_map

    ds_dir = save_dataset(make_synthetic(places=150, dim=16, seed=4), tmp_path / "ds")
    conf = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4, window="causal")
    cpu = load_map(build(conf.replace(device="cpu"), ds_dir, tmp_path / "cpu"), "cpu")
    gpu = load_map(build(conf.replace(device="cuda"), ds_dir, tmp_path / "gpu"), "cuda")
    np.testing.assert_allclose(np.asarray(cpu.shortlist), np.asarray(gpu.shortlist), atol=1e-5)
    q = np.asarray(cpu.shortlist[:20])
    np.testing.assert_array_equal(cpu.search("delta", q, 5, exact=True)[1], gpu.search("delta", q, 5, exact=True)[1])


@pytest.mark.parametrize("precision", ["float16", "bfloat16"])
def test_half_precision_localize_on_the_gpu(world, precision):
    ds, models = world
    full = list(replay(dataset_localizer(ds, models, LocalizeConfig(k=5, top_k=5, device="cuda")), ds.query))
    half_models = {r: SeqNet(**m.config()).cuda().eval() for r, m in models.items()}
    for r, m in half_models.items():
        m.load_state_dict(models[r].state_dict())
        m.provenance = models[r].provenance
    loc = dataset_localizer(ds, half_models, LocalizeConfig(k=5, top_k=5, device="cuda", precision=precision))
    half = list(replay(loc, ds.query))
    assert np.mean([a.ref_index == b.ref_index for a, b in zip(full, half, strict=True)]) >= 0.9
