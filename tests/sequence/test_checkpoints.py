"""Checkpoints: seqnet format round trip, the original SeqNet format, and clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import mutated, read_mutated
from hypothesis import HealthCheck, given, settings

from seqnet.cli import main as cli_main
from seqnet.core.errors import CheckpointError
from seqnet.sequence.checkpoints import load_model, read_checkpoint, save_checkpoint
from seqnet.sequence.model import SeqNet
from seqnet.sequence.original import find_flags


def _reference_descriptors(weight: torch.Tensor, bias: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """SeqNet by hand: [B, L, D] windows, conv weight [D_out, D, w] → mean over time → L2 norm."""
    w = weight.shape[2]
    steps = [sum(x[:, t + k] @ weight[:, :, k].T for k in range(w)) + bias for t in range(x.shape[1] - w + 1)]
    y = torch.stack(steps, 1).mean(1)
    return y / y.norm(dim=1, keepdim=True)


def _original_run(tmp_path, d=12, d_out=6, w=3, seq_len=5, pooling="seqnet", flags=True, where="sibling"):
    """A run of the original code: checkpoints/{checkpoint.pth.tar, model_best.pth.tar, flags.json}."""
    g = torch.Generator().manual_seed(0)
    weight, bias = torch.randn(d_out, d, w, generator=g), torch.randn(d_out, generator=g)
    ckpt_dir = tmp_path / "runs" / "Jan01_l5_0" / "checkpoints"
    ckpt_dir.mkdir(parents=True)
    state = {"epoch": 7, "state_dict": {"pool.0.conv.weight": weight, "pool.0.conv.bias": bias},
             "recalls": {1: np.float64(0.5), 5: np.float64(0.8)}, "best_score": np.float64(0.8),
             "optimizer": {"state": {}, "param_groups": [{"lr": 1e-4, "params": [0, 1]}]}, "parallel": False}
    path = ckpt_dir / "model_best.pth.tar" if where == "sibling" else ckpt_dir.parent / "model_best.pth.tar"
    torch.save(state, path)
    if flags:
        (ckpt_dir / "flags.json").write_text(json.dumps({"seqL": seq_len, "w": w, "outDims": d_out, "pooling": pooling,
                                                         "lr": 1e-4, "margin": 0.1}))
    return path, weight, bias


def test_seqnet_format_round_trip(tmp_path):
    torch.manual_seed(0)
    model = SeqNet(10, 7, 4, 2)
    path = save_checkpoint(tmp_path / "m.pt", model, epoch=3, best_score=0.5)
    loaded = load_model(path)
    assert loaded.config() == model.config() and loaded.role == "seqnet"
    x = torch.randn(5, 4, 10)
    torch.testing.assert_close(loaded(x), model(x))
    assert read_checkpoint(path)["epoch"] == 3
    assert not list(tmp_path.glob(".*tmp"))  # atomic write left nothing behind


def test_model_role():
    assert SeqNet(4, 4, 1, 1).role == "s1"
    assert SeqNet(4, 4, 5, 1).role == "seqnet"
    assert SeqNet(4, 4, 5, 3).role == "seqnet"


@pytest.mark.parametrize("where", ["sibling", "parent"])
def test_original_checkpoint_gives_the_descriptors_of_its_weights(tmp_path, where):
    path, weight, bias = _original_run(tmp_path, where=where)
    assert find_flags(path) is not None
    model = load_model(path)
    assert model.config() == {"in_dims": 12, "out_dims": 6, "seq_len": 5, "w": 3}
    x = torch.randn(9, 5, 12)
    torch.testing.assert_close(model(x), _reference_descriptors(weight, bias, x), rtol=1e-5, atol=1e-6)


def test_original_s1_checkpoint_has_role_s1(tmp_path):
    path, weight, bias = _original_run(tmp_path, w=1, seq_len=5, pooling="s1+seqmatch")
    model = load_model(path)
    assert model.role == "s1"
    x = torch.randn(4, 12)
    torch.testing.assert_close(model(x), _reference_descriptors(weight, bias, x[:, None]), rtol=1e-5, atol=1e-6)


def test_original_without_flags_needs_seq_len(tmp_path):
    path, _, _ = _original_run(tmp_path, flags=False)
    with pytest.raises(CheckpointError, match="seq-len"):
        load_model(path)
    model = load_model(path, seq_len=7)
    assert model.config() == {"in_dims": 12, "out_dims": 6, "seq_len": 7, "w": 3}  # w, dims from the weights


def test_flags_that_contradict_the_weights_are_an_error(tmp_path):
    path, _, _ = _original_run(tmp_path)
    flags = path.parent / "flags.json"
    flags.write_text(json.dumps({"seqL": 5, "w": 5, "outDims": 6}))
    with pytest.raises(CheckpointError, match="w=5"):
        load_model(path)


def test_dimension_mismatch_is_an_error(tmp_path):
    path = save_checkpoint(tmp_path / "m.pt", SeqNet(10, 7, 4, 2))
    with pytest.raises(CheckpointError, match="D=10.*D=16"):
        load_model(path, in_dims=16)


@pytest.mark.parametrize("content", [b"", b"not a checkpoint at all", "truncate"])
def test_corrupted_files_raise_checkpoint_error(tmp_path, content):
    path = tmp_path / "bad.pt"
    if content == "truncate":
        save_checkpoint(path, SeqNet(10, 7, 4, 2))
        path.write_bytes(path.read_bytes()[:200])
    else:
        path.write_bytes(content)
    with pytest.raises(CheckpointError, match="cannot read checkpoint"):
        load_model(path)


def test_wrong_payloads_raise_checkpoint_error(tmp_path):
    torch.save([1, 2, 3], tmp_path / "list.pt")
    with pytest.raises(CheckpointError, match="state_dict"):
        load_model(tmp_path / "list.pt")
    torch.save({"state_dict": {"fc.weight": torch.zeros(3, 3)}}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="conv.weight"):
        load_model(tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not found"):
        load_model(tmp_path / "missing.pt")


def test_cli_eval_with_corrupted_checkpoint_exits_2(tmp_path, synth_dir, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00garbage")
    assert cli_main(["eval", "--dataset", str(synth_dir), "--model", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read checkpoint" in err[0]


def test_cli_eval_with_original_checkpoint(tmp_path, synth_dir, capsys):
    path, _, _ = _original_run(tmp_path, d=16, d_out=8, w=3, seq_len=5)
    argv = ["eval", "--dataset", str(synth_dir), "--model", str(path), "--method", "seqnet,hvpr-seqnet:raw+seqmatch"]
    assert cli_main(argv) == 0
    out = capsys.readouterr().out
    assert "seqnet" in out and "hvpr" in out
    wrong, _, _ = _original_run(tmp_path / "w", d=20)
    assert cli_main(["eval", "--dataset", str(synth_dir), "--model", str(wrong), "--method", "seqnet"]) == 2


def test_a_models_role_is_read_without_its_weights(tmp_path):
    """``model_role``: the role and L of a checkpoint, its 84 MB of weights mapped, not read (a command that does
    not use the model never holds it); the same errors as loading for a file that is not a checkpoint."""
    import subprocess
    import sys

    from seqnet.sequence.checkpoints import model_role

    big = save_checkpoint(tmp_path / "big.pt", SeqNet(2048, 2048, 5, 5))
    assert model_role(big) == ("seqnet", 5)
    assert model_role(save_checkpoint(tmp_path / "s1.pt", SeqNet(8, 4, 1, 1))) == ("s1", 1)
    probe = ("import os, sys; from seqnet.sequence import checkpoints as c; import torch; "  # resident KiB held
             "rss = lambda: int(open('/proc/self/statm').read().split()[1]) * os.sysconf('SC_PAGE_SIZE') // 1024; "
             "a = rss(); kept = getattr(c, sys.argv[1])(sys.argv[2]); print(rss() - a)")
    grown = {f: int(subprocess.run([sys.executable, "-c", probe, f, str(big)], capture_output=True, text=True,
                                   check=True).stdout) for f in ("model_role", "load_model")}
    assert grown["load_model"] > 60 * 1024 and grown["model_role"] < 20 * 1024, grown  # KiB
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="bad.pt"):
        model_role(tmp_path / "bad.pt")


def _small_checkpoint() -> bytes:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        return save_checkpoint(Path(d) / "m.pt", SeqNet(6, 4, 3, 2)).read_bytes()


SMALL = _small_checkpoint()


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=mutated(SMALL))
def test_fuzzed_checkpoint_role_is_read_or_one_error(tmp_path_factory, data):
    """``model_role`` reads a checkpoint mapped, not loaded: a damaged file is its role and L, or one
    CheckpointError, as loading it is."""
    from seqnet.sequence.checkpoints import model_role

    got = read_mutated(model_role, tmp_path_factory.mktemp("fz") / "m.pt", data, CheckpointError)
    assert got is None or (got[0] in ("s1", "seqnet") and isinstance(got[1], int) and got[1] >= 1)


def test_swapped_shortlist_and_rerank_models_are_named(map_models, synth_dir, capsys):
    """An S_1 given as --shortlist-model and an S_L as --rerank-model: refused naming the kind of each and the
    fix (it failed later with 'SeqNet with w=2 needs windows of >= 2 frames, got 1')."""
    from seqnet.sequence.checkpoints import load_models

    sl, s1 = map_models
    with pytest.raises(CheckpointError, match=r"--shortlist-model s1.pt is an S_1 \(L=1, w=1\), not an S_L: give it "
                                              r"as --rerank-model \(the two swapped\?\)"):
        load_models(shortlist_model=s1)
    with pytest.raises(CheckpointError, match=r"--rerank-model sl.pt is an S_4 \(L=4, w=2\), not an S_1"):
        load_models(rerank_model=sl)
    assert set(load_models(shortlist_model=sl, rerank_model=s1)) == {"seqnet", "s1"}
    assert cli_main(["eval", "--dataset", str(synth_dir), "--shortlist-model", str(s1), "--rerank-model", str(sl),
                     "--method", "hvpr", "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is an S_1 (L=1, w=1), not an S_L" in err[0]


def _pair(tmp_path, name: str, seq_len: int, w: int) -> list:
    """Two checkpoints of one kind (another seed each): ``<name>a.pt`` (L=seq_len) and ``<name>b.pt`` (L=seq_len+1
    for an S_L)."""
    out = []
    for i, suffix in enumerate("ab"):
        torch.manual_seed(i)
        length = seq_len + i * (seq_len > 1)
        out.append(save_checkpoint(tmp_path / f"{name}{suffix}.pt", SeqNet(16, 12, length, w)))
    return out


def test_two_checkpoints_of_one_kind_are_refused_naming_both(tmp_path, synth_dir, capsys):
    """``--model A --model B`` of one kind (two S_1, or two S_L): the last replaced the first silently, and a
    second S_L the L of the whole table; refused in one line naming both and the fix (a run of its own each), at
    loading (index build, serve, localize on a map) and at the choice of the models a command uses (eval,
    localize on a dataset), used or not. One S_1 and one S_L, or the same file twice, are one model each."""
    from seqnet.sequence.checkpoints import load_models, used_models

    s1a, s1b = _pair(tmp_path, "s1", 1, 1)
    sla, slb = _pair(tmp_path, "sl", 4, 2)
    second = r"is a second S_1, beside --model .*s1a.pt: a run uses one S_1 and one S_L; to compare them, evaluate " \
             r"each in a run of its own \(one --model each\)"
    with pytest.raises(CheckpointError, match=rf"--model .*s1b.pt {second}"):
        load_models([s1a, s1b])
    with pytest.raises(CheckpointError, match=r"--model .*slb.pt is a second S_L \(L=5; the first has L=4\), beside "
                                              r"--model .*sla.pt"):
        used_models("single", {"s1"}, [sla, slb])  # unused, yet one of them would give L
    with pytest.raises(CheckpointError, match=r"--shortlist-model .*slb.pt is a second S_L .* beside --model "):
        used_models("hvpr", {"seqnet", "s1"}, [sla], shortlist_model=slb)
    with pytest.raises(CheckpointError, match=r"--rerank-model .*s1b.pt is a second S_1"):
        load_models([s1a], rerank_model=s1b)
    assert set(load_models([sla, s1a])) == {"seqnet", "s1"}
    assert list(load_models([s1a, tmp_path / "." / "s1a.pt"], rerank_model=s1a)) == ["s1"]
    assert used_models("s1", {"s1"}, [s1a, s1a], rerank_model=s1a).paths == [s1a]
    for argv in (["eval", "--dataset", str(synth_dir), "--method", "s1"],
                 ["localize", "--dataset", str(synth_dir), "--method", "s1+seqmatch", "--out", str(tmp_path / "l.csv")],
                 ["index", "build", "--dataset", str(synth_dir), "--out", str(tmp_path / "map")]):
        assert cli_main([*argv, "--model", str(s1a), "--model", str(s1b), "--device", "cpu"]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(s1a) in err[0] and str(s1b) in err[0] and "a second S_1" in err[0], err
    assert not (tmp_path / "l.csv").exists() and not (tmp_path / "map").exists()


def test_a_run_folder_given_as_a_checkpoint_names_the_checkpoints_it_holds(tmp_path):
    """``--model RUN`` of a joint run (RUN/seqnet/best.pt, RUN/s1/best.pt) said 'pass RUN/best.pt', which does not
    exist: the two checkpoints are named with their kind; a plain run's best.pt is named as it is."""
    joint = tmp_path / "joint"
    for role, (seq_len, w) in {"seqnet": (4, 2), "s1": (1, 1)}.items():
        (joint / role).mkdir(parents=True)
        save_checkpoint(joint / role / "best.pt", SeqNet(8, 4, seq_len, w))
    with pytest.raises(CheckpointError, match=rf"pass its checkpoints, one --model each: {joint}/s1/best.pt \(S_1\) "
                                              rf"and {joint}/seqnet/best.pt \(S_L\)\)$"):
        load_model(joint)
    with pytest.raises(CheckpointError, match=rf"pass {joint}/s1/best.pt\)$"):
        load_model(joint / "s1")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match=r"pass RUN/best.pt, the checkpoint of a training run\)$"):
        load_model(tmp_path / "empty")


def test_load_models_takes_one_path_as_one_checkpoint(tmp_path):
    """load_models("run/best.pt") read the string's characters ('checkpoint not found: r'); a Path gave
    TypeError: 'PosixPath' object is not iterable."""
    from seqnet.sequence.checkpoints import load_models

    s1a, _ = _pair(tmp_path, "s1", 1, 1)
    for one in (str(s1a), Path(s1a)):
        models = load_models(one)
        assert list(models) == ["s1"] and models["s1"].seq_len == 1
