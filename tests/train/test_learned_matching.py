"""Training S_1 through SeqMatch (--loss seqmatch), speed-augmented S_L windows, and joint S_L + S_1 runs."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.sequence.checkpoints import load_model, read_checkpoint
from seqnet.sequence.windows import speed_windows
from seqnet.train import TrainConfig, train
from seqnet.train.joint import main_joint, s1_config
from seqnet.train.losses import LOSSES
from seqnet.train.mining import compute_cache
from seqnet.train.run import resume_config
from seqnet.train.source import draw_speeds, speed_source, triplet_source

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, out_dims=8,
                   device="cpu", epochs=1)
S1_SEQMATCH = FAST.replace(seq_len=1, w=1, loss="seqmatch", match_len=3, margin=1.0)


def test_seqmatch_loss_trains_s1_and_validates_with_s1_seqmatch(synth_dataset, tmp_path):
    run = train(synth_dataset, S1_SEQMATCH.replace(epochs=2), tmp_path / "r")
    assert run.model.role == "s1" and run.model.config()["seq_len"] == 1
    hist = run.history
    assert all(h["triplets"] > 0 and 0 <= h["recall@1"] <= 1 for h in hist)
    assert hist[-1]["loss"] < hist[0]["loss"]
    stored = read_checkpoint(tmp_path / "r" / "best.pt")
    assert stored["config"]["loss"] == "seqmatch" and stored["config"]["match_len"] == 3  # recorded in the checkpoint
    # the val score is s1+seqmatch at L_m = 3 (not s1 alone)
    from seqnet.eval.evaluate import EvalConfig, evaluate

    model = load_model(tmp_path / "r" / "best.pt")
    ev = evaluate(synth_dataset.split("val"), EvalConfig(methods=("s1+seqmatch",), seq_len=3, device="cpu"),
                  {"s1": model})
    assert ev.results["methods"]["s1+seqmatch"]["recall@1"] == pytest.approx(run.best_score)


def test_seqmatch_mining_cache_is_framewise(synth_dataset):
    conf = S1_SEQMATCH.resolve(synth_dataset)
    src = triplet_source(synth_dataset.split("train"), conf.window_len, conf.window, conf.mining, torch.device("cpu"))
    assert src.q_idx.shape[1] == 3
    torch.manual_seed(0)
    from seqnet.sequence.model import SeqNet

    model = SeqNet(16, 8, 1, 1)
    rows = torch.arange(5)
    q, cache = compute_cache(model, src, rows, framewise=True)
    r = cache.whole(torch.device("cpu"))
    assert q.shape == (5, 3, 8) and r.shape == (len(src.r_idx), 3, 8)
    with torch.no_grad():
        expected = model(src.q_desc[src.q_idx[rows].reshape(-1)]).reshape(5, 3, 8)
    torch.testing.assert_close(q, expected)
    scores = LOSSES["seqmatch"].cross(q, r)
    i, j = 2, 7
    assert scores[i, j].item() == pytest.approx(float(sum((q[i, t] - r[j, t]).norm() for t in range(3))), abs=1e-5)


def test_speed_source_resamples_every_query_window(synth_dataset):
    conf = FAST.replace(seq_len=5, w=3).resolve(synth_dataset)
    src = triplet_source(synth_dataset.split("train"), 5, "centred", conf.mining, torch.device("cpu"))
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    out = speed_source(src, 5, "centred", (0.5, 2.0), g1)
    speeds = draw_speeds(src.n_queries, (0.5, 2.0), g2)
    assert 0.5 <= speeds.min() and speeds.max() <= 2.0 and speeds.std() > 0.1
    expected = speed_windows(src.q_items, 5, "centred", speeds, src.q_bounds)
    np.testing.assert_array_equal(out.q_idx.numpy(), expected)
    np.testing.assert_array_equal(out.q_idx[:, 2].numpy(), src.q_idx[:, 2].numpy())  # same query frames
    assert (out.q_idx != src.q_idx).any() and torch.equal(out.r_idx, src.r_idx) and torch.equal(out.q_pos, src.q_pos)
    assert speed_source(src, 5, "centred", None, g1) is src


def test_speed_augmented_training_resumes_exactly(synth_dataset, tmp_path):
    conf = FAST.replace(seq_len=3, w=2, speed_augment=(0.5, 2.0))
    straight = train(synth_dataset, conf.replace(epochs=2), tmp_path / "a")
    train(synth_dataset, conf, tmp_path / "b")
    train(synth_dataset, resume_config(tmp_path / "b", epochs=2), tmp_path / "b", resume=True)
    a, b = read_checkpoint(tmp_path / "a" / "last.pt"), read_checkpoint(tmp_path / "b" / "last.pt")
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    plain = train(synth_dataset, FAST.replace(seq_len=3, w=2, epochs=2), tmp_path / "c")
    assert not torch.equal(plain.model.conv.weight, straight.model.conv.weight)  # the augmentation changes training


def test_joint_training_writes_both_runs_and_resumes(synth_dataset, synth_dir, tmp_path):
    conf = FAST.replace(seq_len=3, w=2)
    dirs = main_joint(conf, s1_config(conf, "seqmatch", 3e-3), synth_dir, tmp_path / "j")
    assert dirs == {"seqnet": tmp_path / "j" / "seqnet", "s1": tmp_path / "j" / "s1"}
    assert load_model(dirs["seqnet"] / "best.pt").role == "seqnet" and load_model(dirs["s1"] / "best.pt").role == "s1"
    s1 = read_checkpoint(dirs["s1"] / "best.pt")["config"]
    assert s1["loss"] == "seqmatch" and s1["lr"] == 3e-3 and s1["match_len"] == 5
    stored = json.loads((tmp_path / "j" / "joint.json").read_text())
    assert stored["config"]["seqnet"]["seq_len"] == 3 and stored["config"]["s1"]["loss"] == "seqmatch"
    main_joint(None, None, None, None, resume=tmp_path / "j", changes={"epochs": 2})
    assert read_checkpoint(dirs["seqnet"] / "last.pt")["epoch"] == 2 == read_checkpoint(dirs["s1"] / "last.pt")["epoch"]
    with pytest.raises(ConfigError, match="not empty"):
        main_joint(conf, None, synth_dir, tmp_path / "j")
    with pytest.raises(ConfigError, match="seq_len >= 2"):
        main_joint(conf.replace(seq_len=1, w=1), None, synth_dir, tmp_path / "k")
    with pytest.raises(ConfigError, match="not a joint run"):
        main_joint(None, None, synth_dir, None, resume=dirs["s1"])


def test_cli_loss_speed_and_joint(synth_dir, tmp_path, capsys):
    common = ["--dataset", str(synth_dir), "--epochs", "1", "--optimizer", "adam", "--n-neg-sample", "50",
              "--out-dims", "8", "--device", "cpu"]
    assert cli_main(["train", *common, "--out", str(tmp_path / "s1"), "--seq-len", "1", "--w", "1",
                     "--loss", "seqmatch", "--match-len", "3"]) == 0
    assert read_checkpoint(tmp_path / "s1" / "best.pt")["config"]["loss"] == "seqmatch"
    assert cli_main(["train", *common, "--out", str(tmp_path / "j"), "--seq-len", "3", "--w", "2", "--joint",
                     "--s1-loss", "seqmatch", "--speed-augment", "0.5:2"]) == 0
    out = capsys.readouterr().out
    assert out.count("best val R@1") == 3 and "--rerank-model" in out
    assert f"HVPR: seqnet eval --dataset {synth_dir.resolve()} --method hvpr" in out  # not a literal DIR
    assert read_checkpoint(tmp_path / "j" / "seqnet" / "best.pt")["config"]["speed_augment"] == [0.5, 2.0]
    assert read_checkpoint(tmp_path / "j" / "s1" / "best.pt")["config"]["speed_augment"] is None
    assert cli_main(["train", "--resume", str(tmp_path / "j"), "--epochs", "2"]) == 0
    assert read_checkpoint(tmp_path / "j" / "s1" / "last.pt")["epoch"] == 2
    capsys.readouterr()
    bad = [["--loss", "seqmatch"], ["--speed-augment", "2:1"], ["--loss", "nope"], ["--joint", "--loss", "seqmatch"]]
    for i, case in enumerate(bad):
        assert cli_main(["train", *common, "--out", str(tmp_path / f"bad{i}"), *case]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "error" in err[0], err


S1_VSEQMATCH = S1_SEQMATCH.replace(loss="vseqmatch")


def test_vseqmatch_reference_windows_are_widened_inside_their_sequences():
    from seqnet.data.traverse import Traverse
    from seqnet.train.source import widen_windows

    bounds = np.array([[0, 10]] * 10 + [[10, 14]] * 4)
    t = Traverse(np.ones((14, 2), np.float32), np.arange(14.0), seq_bounds=bounds)
    items = np.arange(1, 13)
    idx = items[:, None] - 1 + np.arange(3)[None, :]  # centred 3-frame windows
    kept, wide = widen_windows(t, items, idx, 1)
    naive = [(i, list(range(i - 2, i + 3))) for i in items
             if i - 2 >= bounds[i][0] and i + 2 < bounds[i][1]]
    assert kept.tolist() == [i for i, _ in naive] and wide.tolist() == [w for _, w in naive]
    assert widen_windows(t, items, idx, 0)[1] is idx


@pytest.mark.parametrize(("loss", "method"), [("vseqmatch", "s1+vseqmatch"), ("graph", "s1+graph")])
def test_matcher_losses_train_s1_on_widened_references_and_validate_with_their_matcher(synth_dataset, tmp_path,
                                                                                       loss, method):
    conf = S1_VSEQMATCH.replace(loss=loss).resolve(synth_dataset)
    assert (conf.window_len, conf.ref_pad) == (3, 1)
    src = triplet_source(synth_dataset.split("train"), conf.window_len, conf.window, conf.mining,
                         torch.device("cpu"), conf.ref_pad)
    assert src.q_idx.shape[1] == 3 and src.r_idx.shape[1] == 5
    run = train(synth_dataset, conf.replace(epochs=2), tmp_path / "r")
    assert all(h["triplets"] > 0 for h in run.history) and run.history[-1]["loss"] < run.history[0]["loss"]
    from seqnet.eval.evaluate import EvalConfig, evaluate

    model = load_model(tmp_path / "r" / "best.pt")
    assert read_checkpoint(tmp_path / "r" / "best.pt")["config"]["loss"] == loss
    ev = evaluate(synth_dataset.split("val"), EvalConfig(methods=(method,), seq_len=3, device="cpu"), {"s1": model})
    assert ev.results["methods"][method]["recall@1"] == pytest.approx(run.best_score)
    with pytest.raises(ConfigError, match=f"the {loss} loss trains S_1"):
        TrainConfig(loss=loss, seq_len=5, w=5)
