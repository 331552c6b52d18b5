"""S_L at another test length than it was trained with (methods.checks.check_models, shared by eval, localize and
index build): any L >= w runs, is recorded (``model_seq_len``) with one info line; L < w is refused."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.replay import dataset_localizer
from seqnet.methods.checks import check_models, model_lengths
from seqnet.sequence.checkpoints import save_checkpoint
from seqnet.sequence.model import SeqNet


@pytest.fixture()
def s10():
    """S_L trained (here: initialised) at the paper's Nordland L_d = 10, w = 5."""
    torch.manual_seed(0)
    return SeqNet(8, 8, 10, 5)


def _info_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "trained with L=10" in r.getMessage()]


def test_sl_trained_at_10_is_evaluated_at_5_and_recorded(s10, caplog):
    ds = make_synthetic(places=150, dim=8, seed=0).split("test")
    s10.provenance = ds.reference.provenance
    with caplog.at_level("INFO", logger="seqnet"):
        ev = evaluate(ds, EvalConfig(methods=("seqnet",), seq_len=5, device="cpu"), {"seqnet": s10})
    lines = _info_lines(caplog)
    assert len(lines) == 1 and "L=5" in lines[0] and "w=5" in lines[0] and "1 outputs" in lines[0]
    cfg = ev.results["config"]
    assert cfg["seq_len"] == 5 and cfg["model_seq_len"] == {"seqnet": 10}
    assert cfg["models"]["seqnet"]["seq_len"] == 10
    # the descriptor really is S_L applied to 5-frame windows: the literal convolution on the query's windows
    start = ev.q_items[20] - 2  # its centred window of 5
    x = torch.as_tensor(ds.query.descriptors[start:start + 5][None], dtype=torch.float32)
    assert ev.results["methods"]["seqnet"]["queries"] > 0
    np.testing.assert_allclose(s10(x).detach().numpy(), s10.forward_conv(x).detach().numpy(), atol=1e-5)


def test_same_length_logs_nothing_and_shorter_than_w_is_refused(s10, caplog):
    ds = make_synthetic(places=150, dim=8, seed=0).split("test")
    s10.provenance = ds.reference.provenance
    with caplog.at_level("INFO", logger="seqnet"):
        evaluate(ds, EvalConfig(methods=("seqnet",), device="cpu"), {"seqnet": s10})  # L = the model's 10
    assert _info_lines(caplog) == []
    for allow in (False, True):
        with pytest.raises(ConfigError, match=r"L=4, shorter than its convolution width w=5; hint: --seq-len L "
                                              r"with L >= 5"):
            evaluate(ds, EvalConfig(methods=("seqnet",), seq_len=4, device="cpu", allow_mismatch=allow),
                     {"seqnet": s10})


def test_check_models_is_the_one_check_localize_uses(s10):
    ds = make_synthetic(places=150, dim=8, seed=0)
    s10.provenance = ds.reference.provenance
    check_models({"seqnet": s10}, 8, ds.reference.provenance, "x", 7)
    with pytest.raises(ConfigError, match="the map uses L=3"):
        check_models({"seqnet": s10}, 8, ds.reference.provenance, "x", 3, use="the map uses")
    loc = dataset_localizer(ds, {"seqnet": s10}, LocalizeConfig(method="seqnet", seq_len=5, device="cpu"))
    assert loc.seq_len == 5
    with pytest.raises(ConfigError, match="shorter than its convolution width"):
        dataset_localizer(ds, {"seqnet": s10}, LocalizeConfig(method="seqnet", seq_len=4, device="cpu"))
    assert model_lengths({"seqnet": s10, "s1": SeqNet(8, 8, 1, 1)}) == {"s1": 1, "seqnet": 10}


def test_cli_eval_and_index_build_record_the_trained_length(s10, tmp_path, capsys):
    from seqnet.cli import main as cli_main

    ds = make_synthetic(places=150, dim=8, seed=0)
    s10.provenance = ds.reference.provenance
    save_dataset(ds, tmp_path / "ds")
    save_checkpoint(tmp_path / "s10.pt", s10)
    assert cli_main(["eval", "--dataset", str(tmp_path / "ds"), "--model", str(tmp_path / "s10.pt"),
                     "--seq-len", "5", "--methods", "seqnet", "--device", "cpu", "--out", str(tmp_path / "ev")]) == 0
    res = json.loads((tmp_path / "ev" / "results.json").read_text())
    assert res["config"]["seq_len"] == 5 and res["config"]["model_seq_len"] == {"seqnet": 10}
    assert cli_main(["index", "build", "--dataset", str(tmp_path / "ds"), "--model", str(tmp_path / "s10.pt"),
                     "--seq-len", "5", "--rerank", "raw+seqmatch", "--device", "cpu",
                     "--out", str(tmp_path / "map")]) == 0
    assert json.loads((tmp_path / "map" / "map.json").read_text())["source"]["model_seq_len"] == {"seqnet": 10}
    capsys.readouterr()
    assert cli_main(["eval", "--dataset", str(tmp_path / "ds"), "--model", str(tmp_path / "s10.pt"),
                     "--seq-len", "3", "--methods", "seqnet", "--device", "cpu", "--out", str(tmp_path / "ev3")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "shorter than its convolution width w=5" in err[0]


@pytest.mark.parametrize("dataset_path, config", [
    ("ds\x00/x", {"train_split": "train"}),
    ("DATASET", {"train_split": ["train"]}),
    ("DATASET", {"train_split": {"query": [0, 5]}}),
    (["DATASET"], {"train_split": "train"}),
    ("DATASET", {"train_split": "x" * 10_000}),
    ("DATASET", {"train_split": 3}),
])
def test_an_unusable_training_record_is_ignored(tmp_path, caplog, dataset_path, config):
    """``dataset_path`` and ``train_split`` come from a checkpoint file: a NUL byte (ValueError from resolve) or a
    list split (TypeError in a dict lookup) crashed the leakage check; such a record is now ignored, said at
    debug level."""
    from seqnet.methods.checks import leakage
    from seqnet.sequence.checkpoints import load_model

    ds = make_synthetic(places=150, dim=8, seed=0)
    ds_dir = save_dataset(ds, tmp_path / "ds")
    model = SeqNet(8, 8, 3, 2)
    model.provenance = ds.reference.provenance
    path = save_checkpoint(tmp_path / "m.pt", model, config=config,
                           dataset_path=str(ds_dir) if dataset_path == "DATASET" else dataset_path)
    loaded = load_model(path)
    with caplog.at_level("DEBUG", logger="seqnet"):
        assert leakage({"seqnet": loaded}, ds_dir, ds, "all") == []
    assert any("ignoring the training record" in r.getMessage() for r in caplog.records)
    good = save_checkpoint(tmp_path / "g.pt", model, config={"train_split": "train"}, dataset_path=str(ds_dir))
    assert len(leakage({"seqnet": load_model(good)}, ds_dir, ds, "all")) == 1


@settings(max_examples=150, deadline=None)
@given(record=st.dictionaries(st.sampled_from(["dataset", "split", "checkpoint"]),
                              st.none() | st.integers() | st.text(max_size=12) | st.lists(st.text(max_size=3)),
                              max_size=3))
def test_fuzzed_training_records_never_crash_the_check(record):
    from types import SimpleNamespace

    from seqnet.methods.checks import leakage

    ds = FUZZ_DS
    assert isinstance(leakage({"seqnet": SimpleNamespace(trained_on=record)}, "/nonexistent", ds, "all"), list)


FUZZ_DS = make_synthetic(places=100, dim=8, seed=0)


def test_a_missing_model_names_the_model_free_method_to_use():
    from seqnet.core.errors import ConfigError
    from seqnet.methods.checks import check_methods, check_windows_fit
    from seqnet.methods.grammar import parse_method

    for name, free in (("hvpr", "raw+seqmatch"), ("s1", "single"), ("seqnet", "delta"), ("s1+graph", "raw+graph")):
        with pytest.raises(ConfigError, match=rf"; or the model-free '{re.escape(free)}'$"):
            check_methods([parse_method(name)], {}, 5)
    with pytest.raises(ConfigError, match=r"\(1 frame\); use a shorter --seq-len or a longer split"):
        check_windows_fit(5, 1, "the query traverse")


def test_a_window_too_long_names_the_option_that_set_it(synth_dir, capsys):
    """--match-len longer than a traverse is named as such (the message said --seq-len when L_m set the window)."""
    from seqnet.cli import main as cli_main
    from seqnet.core.errors import ConfigError
    from seqnet.sequence.windows import Windows

    for extra, option in ((["--seq-len", "3", "--match-len", "5000"], "--match-len"),
                          (["--seq-len", "5000", "--match-len", "3"], "--seq-len")):
        assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch", *extra, "--device",
                         "cpu"]) == 2
        err = capsys.readouterr().err
        assert f"use a shorter {option} or a longer split" in err and f"{option[2:].replace('-', '_')}=5000" in err
    with pytest.raises(ConfigError, match="use a shorter --match-len$"):
        _no_window(Windows(3, 9))  # no frame of 4 fits L_m = 9
    assert Windows(5, 5).longest_option == "--seq-len"


def _no_window(windows) -> None:
    from seqnet.sequence.windows import WindowedItems

    WindowedItems()._set_side(windows, 4, None, "query")


def test_the_training_queries_hint_names_a_split_that_exists(synth_dataset, tmp_path):
    """The warning about training queries evaluated says ``--split S`` with S a split of the dataset: ``Test`` when
    the user named it so, else a split without training queries (it said ``--split test`` whatever the splits)."""
    import dataclasses
    from types import SimpleNamespace

    from seqnet.methods.checks import leakage

    def said(splits, evaluated):
        ds = dataclasses.replace(synth_dataset, splits=splits)
        record = {"dataset": str(tmp_path), "split": "Train", "checkpoint": "r/best.pt"}
        return leakage({"s1": SimpleNamespace(trained_on=record)}, tmp_path, ds, evaluated)

    s = synth_dataset.splits
    caps = {"Train": s["train"], "Val": s["val"], "Test": s["test"]}
    assert said(caps, "Train")[0].endswith("(hint: --split Test (EvalConfig(split='Test') in Python))")
    assert said({"Train": s["train"], "Val": s["val"]}, "all")[0].endswith("(hint: --split Val"
                                                                           " (EvalConfig(split='Val') in Python))")
    assert said({"Train": s["train"]}, "all")[0].endswith("(hint: --split 105:197"
                                                          " (EvalConfig(split='105:197') in Python)"
                                                          " (queries free of the models' "
                                                          "training and epoch-selection ones))")
    assert said({"Train": s["train"], "test": s["test"]}, "all")[0].endswith("(hint: --split test"
                                                                             " (EvalConfig(split='test') in Python))")


def test_a_model_of_other_dimensions_names_the_dataset_it_was_trained_on():
    """A model trained on DS-pca32 (``train --pca 32`` on DS) evaluated on DS: the error names the dataset its
    checkpoint records; a model that records none keeps the bare error."""
    model = SeqNet(32, 8, 1, 1)
    with pytest.raises(ConfigError) as bare:
        check_models({"s1": model}, 2048, None, "dataset 'DS'", 1)
    assert str(bare.value) == "the s1 model (S_1) expects D=32 descriptors but the dataset has D=2048"
    model.trained_on = {"dataset": "/data/DS-pca32", "split": "train"}
    with pytest.raises(ConfigError) as named:
        check_models({"s1": model}, 2048, None, "dataset 'DS'", 1)
    assert str(named.value) == ("the s1 model (S_1) expects D=32 descriptors but the dataset has D=2048; hint: it "
                                "was trained on the dataset /data/DS-pca32: --dataset /data/DS-pca32")
    with pytest.raises(ConfigError, match="trained on the dataset /data/DS-pca32: a map built from that dataset$"):
        check_models({"s1": model}, 2048, None, "the map 'M'", 1)


@settings(max_examples=200, deadline=None)
@given(a=st.integers(0, 40), lo=st.integers(-5, 90), span=st.integers(0, 60), every=st.integers(1, 9))
def test_kept_count_matches_a_loop(a, lo, span, every):
    """The queries ``a, a + every, ...`` of a re-sampled split that lie in ``lo:hi``, against a loop."""
    from seqnet.methods.checks import kept_count

    hi = lo + span
    assert kept_count(a, lo, hi, every) == sum(lo <= q < hi for q in range(a, max(a, hi) + every, every))


def test_models_under_swapped_roles_are_named_with_the_fix():
    """{"seqnet": S_1, "s1": S_5} failed with 'SeqNet with w=3 needs windows of >= 3 frames, got 1'."""
    from seqnet.core.errors import ConfigError
    from seqnet.methods.checks import check_models
    from seqnet.sequence.model import SeqNet

    s5, s1 = SeqNet(8, 4, 5, 3), SeqNet(8, 4, 1, 1)
    with pytest.raises(ConfigError, match=r"models\['s1'\] is an S_5 \(L=5, w=3\): the 's1' role takes an S_1; "
                                          r"did you swap the roles\?"):
        check_models({"s1": s5}, 8, None, "dataset 'x'", 5)
    with pytest.raises(ConfigError, match=r"models\['seqnet'\] is an S_1 \(L=1, w=1\)"):
        check_models({"seqnet": s1, "s1": s5}, 8, None, "dataset 'x'", 5)
    check_models({"seqnet": s5, "s1": s1}, 8, None, "dataset 'x'", 5)  # the right roles: no error
