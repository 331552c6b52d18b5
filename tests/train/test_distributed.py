"""Distributed training (torchrun, DDP on gloo): the helpers, sharded mining, and two CPU processes
against one.

Tolerance of the 2-process vs 1-process comparison: ``atol = 1e-5`` on the float32 weights (|w| <=
~0.35). The two runs mine the same triplets from the same random numbers (the negative cache and
the generator state are compared exactly); what differs is only float rounding: each rank sums its
share of the batch's hinges, DDP adds the two partial gradients, and each rank describes half of the
reference windows in another GEMM shape. Measured on this machine: max |Δw| ~ 1e-7 after one epoch
(7 Adam steps at lr 1e-2) and after resuming to epoch 2; 1e-5 leaves two orders of magnitude for
other BLAS builds while a wrong update moves the weights much more (DDP's default average instead of
the sum: 7.5e-4 after this epoch, and other negatives mined).
"""

from __future__ import annotations

import json
import os
import runpy
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from seqnet.cli.runtime import report_error
from seqnet.core.errors import ConfigError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.sequence.checkpoints import read_checkpoint
from seqnet.sequence.model import SeqNet
from seqnet.train import TrainConfig, train
from seqnet.train.distributed import World, env_world
from seqnet.train.losses import triplet_loss
from seqnet.train.mining import compute_cache, mine_queries
from seqnet.train.source import triplet_source

SRC = Path(__file__).resolve().parents[2] / "src"
ATOL = 1e-5
CONF = TrainConfig(optimizer="adam", lr=1e-2, n_neg_sample=50, cache_refresh=40, seq_len=3, w=2, out_dims=8,
                   device="cpu", epochs=1)
ARGS = ["--device", "cpu", "--optimizer", "adam", "--lr", "1e-2", "--n-neg-sample", "50", "--cache-refresh", "40",
        "--seq-len", "3", "--w", "2", "--out-dims", "8"]


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_shares_split_every_batch_into_contiguous_balanced_parts(size):
    n, batch = 37, 8
    shares = torch.stack([World(size, r).shares(n, batch) for r in range(size)])
    assert (shares.sum(0) == 1).all()  # every query has exactly one rank
    for b in range(0, n, batch):
        counts = shares[:, b : b + batch].sum(1)
        assert counts.max() - counts.min() <= 1
        owner = shares[:, b : b + batch].float().argmax(0)
        assert (owner[1:] >= owner[:-1]).all()  # contiguous, in rank order
    parts = [World(size, r).part(10) for r in range(size)]
    assert sum((list(range(10))[p] for p in parts), []) == list(range(10))


def test_a_single_process_world_is_the_identity():
    w, x = World(), torch.arange(6.0).reshape(3, 2)
    assert w.shares(5, 2).all() and w.part(7) == slice(0, 7)
    assert w.gather_rows(x, 3) is x and w.merge_rows(torch.ones(3, dtype=torch.bool), x) is x
    assert w.sum_stats({"a": 1.0}) == {"a": 1.0} and w.rank0(lambda: 5) == 5 and w.agree(lambda: 6) == 6
    model = SeqNet(4, 4, 3, 2)
    assert w.wrap(model) is model and w.device("cpu") == torch.device("cpu")


def test_env_world_reads_torchrun_variables(monkeypatch):
    for key in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(key, raising=False)
    assert env_world() == World()
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert env_world().size == 1
    monkeypatch.setenv("WORLD_SIZE", "2")
    with pytest.raises(ConfigError, match="RANK, LOCAL_RANK, MASTER_ADDR, MASTER_PORT not set .*torchrun"):
        env_world()
    monkeypatch.setenv("WORLD_SIZE", "two")
    with pytest.raises(ConfigError, match="WORLD_SIZE='two' must be an integer"):
        env_world()


@pytest.mark.parametrize(("size", "batch"), [(2, 5), (4, 2)])  # (4, 2): half the ranks idle in every batch
def test_sharded_mining_draws_the_same_numbers_and_merges_to_the_single_process_cache(synth_dataset, size, batch):
    conf = CONF.resolve(synth_dataset)
    src = triplet_source(synth_dataset.split("train"), conf.seq_len, conf.window, conf.mining, torch.device("cpu"))
    q_feat, r_feat = compute_cache(SeqNet(16, 8, 3, 2), src, torch.arange(src.n_queries))
    rows = torch.randperm(src.n_queries, generator=torch.Generator().manual_seed(3))[:45]
    mining, block = conf.mining.replace(n_neg_sample=20), 7 * len(r_feat)  # random draws; blocks of 7 queries
    start = torch.full((src.n_queries, conf.n_negatives), -1, dtype=torch.long)
    start[rows[::3]] = torch.randint(0, len(r_feat), (len(rows[::3]), conf.n_negatives))  # some cached negatives
    gen, cache = torch.Generator().manual_seed(0), start.clone()
    full = mine_queries(src, rows, q_feat[rows], r_feat, mining, gen, cache, block_elems=block)
    merged = start.clone()
    for rank in range(size):
        own = World(size, rank).shares(len(rows), batch)
        g, c = torch.Generator().manual_seed(0), start.clone()
        part = mine_queries(src, rows, q_feat[rows[own]], r_feat, mining, g, c, block_elems=block, own=own)
        assert torch.equal(g.get_state(), gen.get_state())  # every rank's generator stays in step
        for name in ("positive", "negatives", "valid"):
            assert torch.equal(getattr(part, name), getattr(full[own], name)), name
        torch.testing.assert_close(part.d_neg, full[own].d_neg, rtol=0, atol=1e-6)  # GEMMs of other shapes
        merged[rows[own]] = c[rows[own]]
    assert torch.equal(merged, cache) and not torch.equal(cache, start)


def test_the_loss_shares_of_a_batch_sum_to_its_mean():
    g = torch.Generator().manual_seed(0)
    q, p, n = (torch.randn(k, 6, generator=g, requires_grad=True) for k in (4, 4, 9))
    anchor = torch.tensor([0, 0, 1, 1, 1, 2, 3, 3, 3])
    whole = triplet_loss(q, p, n, anchor, 0.5)
    first = triplet_loss(q[:2], p[:2], n[:5], anchor[:5], 0.5, total=9)
    second = triplet_loss(q[2:], p[2:], n[5:], anchor[5:] - 2, 0.5, total=9)
    assert float((first.loss + second.loss).detach()) == pytest.approx(float(whole.loss.detach()), rel=1e-6)
    with pytest.raises(ConfigError, match="total must be >= the 5 triplets"):
        triplet_loss(q[:2], p[:2], n[:5], anchor[:5], 0.5, total=4)


def test_rank0_errors_reach_every_rank_and_are_printed_once(monkeypatch, capsys):
    import torch.distributed as dist

    err = ConfigError("run directory R is not empty")  # as rank 1 receives it (unpickled: a fresh object)
    monkeypatch.setattr(dist, "broadcast_object_list", lambda box, src: box.__setitem__(0, (False, err)))
    with pytest.raises(ConfigError) as copy:
        World(2, 1, 1, "gloo").rank0(lambda: pytest.fail("only rank 0 runs it"))
    assert copy.value.reported_elsewhere
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "1")
    assert report_error("train", copy.value) == 2 and capsys.readouterr().err == ""  # rank 0 prints it
    assert report_error("train", ConfigError("no GPU")) == 2
    assert capsys.readouterr().err == "seqnet train: error: rank 1: no GPU\n"
    other = ConfigError("run directory R is not empty")
    monkeypatch.setattr(dist, "all_gather_object", lambda out, obj: out.__setitem__(slice(None), [None, other]))
    with pytest.raises(ConfigError, match="not empty") as first:
        World(2, 0, 0, "gloo").agree(lambda: 1)  # rank 1 failed: rank 0 raises (and reports) its error
    assert not getattr(first.value, "reported_elsewhere", False)


def test_python_dash_m_seqnet_runs_the_cli(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["seqnet", "--version"])
    with pytest.raises(SystemExit) as done:
        runpy.run_module("seqnet", run_name="__main__")
    assert done.value.code == 0 and capsys.readouterr().out.startswith("seqnet ")


# --- two processes (torchrun, gloo on 127.0.0.1) against one ---------------------------------------------------

WORKER = """
import shutil, sys
from seqnet.cli import main
from seqnet.train.distributed import env_world

data, out, copy, *args = sys.argv[1:]
rc = main(["train", "--dataset", data, "--out", out, "--epochs", "1", *args])
if env_world().is_rank0:
    shutil.copytree(out, copy)  # epoch 1 (the other rank waits for rank 0 in the next train's setup)
sys.exit(rc or main(["train", "--resume", out, "--epochs", "2"]))
"""


def _torchrun(script: Path, args: list[str], logs: Path) -> list[str]:
    """``torchrun --standalone --nproc-per-node 2 SCRIPT ARGS`` (gloo on 127.0.0.1); each rank's output."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1"}
    if Path("/sys/class/net/lo").exists():
        env["GLOO_SOCKET_IFNAME"] = "lo"  # gloo on the loopback only
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2", "--local-addr",
           "127.0.0.1", "--log-dir", str(logs), "--redirects", "3", str(script), *args]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        proc.terminate()  # torchrun stops its workers (they run in sessions of their own)
        try:
            proc.communicate(timeout=30)
        finally:
            proc.kill()
        pytest.fail("torchrun did not finish in 240 s")
    out = ["".join(p.read_text() for p in sorted(logs.rglob(f"attempt_0/{r}/std*.log"))) for r in range(2)]
    assert proc.returncode == 0, (err[-3000:], out)
    return out


def _max_diff(a: Path, b: Path) -> float:
    sa, sb = read_checkpoint(a)["state_dict"], read_checkpoint(b)["state_dict"]
    return max(float((sa[k] - sb[k]).abs().max()) for k in sa)


@pytest.fixture(scope="module")
def two_ranks(tmp_path_factory):
    """One torchrun launch: 2 ranks train 1 epoch (copied to ``epoch1``), then resume the run to epoch 2."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_gloo_available()):
        pytest.skip("torch.distributed with gloo is not available in this torch build")
    tmp = tmp_path_factory.mktemp("ddp")
    data = save_dataset(make_synthetic(places=200, dim=8), tmp / "ds")
    (tmp / "worker.py").write_text(WORKER)
    logs = _torchrun(tmp / "worker.py", [str(data), str(tmp / "ddp"), str(tmp / "epoch1"), *ARGS], tmp / "logs")
    return tmp, load_dataset(data), logs


def test_two_processes_match_one_with_the_same_global_batch(two_ranks):
    tmp, ds, logs = two_ranks
    train(ds, CONF, tmp / "single")
    assert _max_diff(tmp / "single" / "last.pt", tmp / "epoch1" / "last.pt") <= ATOL
    one, two = read_checkpoint(tmp / "single" / "last.pt"), read_checkpoint(tmp / "epoch1" / "last.pt")
    # the same random numbers were drawn and the same hard negatives mined
    assert torch.equal(one["train_state"]["rng"]["generator"], two["train_state"]["rng"]["generator"])
    assert torch.equal(one["train_state"]["neg_cache"], two["train_state"]["neg_cache"])
    h1, h2 = one["train_state"]["history"][0], two["train_state"]["history"][0]
    assert {k: v for k, v in h1.items() if k != "loss"} == {k: v for k, v in h2.items() if k != "loss"}
    assert h1["loss"] == pytest.approx(h2["loss"], rel=1e-6)
    # rank 0 alone wrote the run (one TensorBoard file, no lock left) and logged; its start line names the world
    files = sorted(p.name for p in (tmp / "epoch1").iterdir())
    assert len(files) == 5 and files[:3] == [".seqnet-manifest.json", "best.pt", "config.json"], files
    assert files[4] == "last.pt" and files[3].startswith("events.out.tfevents") and not list(tmp.glob(".*.lock"))
    assert files[3] in json.loads((tmp / "epoch1" / ".seqnet-manifest.json").read_text())["files"]
    assert "world size 2 (gloo)" in logs[0] and "trained S_3 (w=2, D=8->8) to epoch 1 of 1;" in logs[0]
    assert logs[1].strip() == "", logs[1]


def test_two_processes_resume_as_one_would(two_ranks):
    tmp, ds, logs = two_ranks
    train(ds, CONF.replace(epochs=2), tmp / "straight")
    assert _max_diff(tmp / "straight" / "last.pt", tmp / "ddp" / "last.pt") <= ATOL
    resumed, straight = read_checkpoint(tmp / "ddp" / "last.pt"), read_checkpoint(tmp / "straight" / "last.pt")
    assert resumed["epoch"] == 2 and [h["epoch"] for h in resumed["train_state"]["history"]] == [1, 2]
    assert torch.equal(straight["train_state"]["neg_cache"], resumed["train_state"]["neg_cache"])
    assert "resuming" in logs[0] and logs[0].count("world size 2 (gloo)") == 2
    assert len(list((tmp / "ddp").glob("events.out.tfevents*"))) == 2  # one per launch of rank 0


SEQMATCH_WORKER = """
import sys
from seqnet.cli import main

data, out, *args = sys.argv[1:]
sys.exit(main(["train", "--dataset", data, "--out", out, "--epochs", "1", *args]))
"""
SEQMATCH_ARGS = ["--device", "cpu", "--optimizer", "adam", "--lr", "1e-2", "--n-neg-sample", "50",
                 "--cache-refresh", "40", "--seq-len", "1", "--w", "1", "--out-dims", "8", "--loss", "seqmatch",
                 "--match-len", "3"]


def test_two_processes_train_the_seqmatch_loss_as_one(tmp_path):
    """The SeqMatchNet-style loss (framewise mining cache, gathered between ranks) under torchrun = one process."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_gloo_available()):
        pytest.skip("torch.distributed with gloo is not available in this torch build")
    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    (tmp_path / "worker.py").write_text(SEQMATCH_WORKER)
    logs = _torchrun(tmp_path / "worker.py", [str(data), str(tmp_path / "ddp"), *SEQMATCH_ARGS], tmp_path / "logs")
    conf = CONF.replace(seq_len=1, w=1, loss="seqmatch", match_len=3)
    train(load_dataset(data), conf, tmp_path / "single")
    assert _max_diff(tmp_path / "single" / "last.pt", tmp_path / "ddp" / "last.pt") <= ATOL
    one, two = read_checkpoint(tmp_path / "single" / "last.pt"), read_checkpoint(tmp_path / "ddp" / "last.pt")
    assert one["config"]["loss"] == two["config"]["loss"] == "seqmatch"
    assert torch.equal(one["train_state"]["neg_cache"], two["train_state"]["neg_cache"])
    assert "world size 2 (gloo)" in logs[0] and logs[1].strip() == ""
