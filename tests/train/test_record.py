"""What a run's checkpoints record of its splits, and the refusal to resume on splits rebuilt since
(:mod:`seqnet.train.record`)."""

import json

import pytest

from seqnet.core.errors import CheckpointError, ConfigError
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.sequence.checkpoints import read_checkpoint
from seqnet.train.config import TrainConfig
from seqnet.train.loop import main

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=1, w=1,
                   out_dims=8, device="cpu", epochs=1)


def test_resume_on_a_dataset_rebuilt_with_new_splits_is_refused(tmp_path):
    """The same descriptors, dataset.json rewritten with new splits: resuming would train on other queries and
    choose the epoch on a val split that held its training queries; refused in one line naming the change and
    the run's splits (it went on silently). Unchanged splits resume."""
    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    run = main(FAST, data, tmp_path / "run")
    best = read_checkpoint(run / "best.pt")
    assert (best["train_queries"], best["val_queries"], best["train_references"]) == ([0, 119], [119, 145], [0, 116])
    meta = json.loads((data / "dataset.json").read_text())
    splits, name = meta["splits"], meta.get("name")
    meta["splits"] = {"train": {"reference": [0, 194], "query": [50, 191]}, "val": {"reference": [0, 194],
                                                                                     "query": [0, 50]}}
    (data / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError) as e:
        main(FAST.replace(epochs=2), None, None, resume=run)
    assert str(e.value) == (
        f"the splits of dataset {name!r} changed since the run in {run} started (train queries 0:119 -> 50:191, train "
        "references 0:116 -> 0:194, val queries 119:145 -> 0:50, val references 116:151 -> 0:194): resuming would "
        "train and choose its epoch on other queries (hint: start a new run, seqnet train --out NEW, or rebuild "
        f"{name!r} with the run's splits (--split train=0:116,0:119 --split val=116:151,119:145))")
    meta["splits"] = splits
    (data / "dataset.json").write_text(json.dumps(meta))
    main(FAST.replace(epochs=2), None, None, resume=run)
    assert read_checkpoint(run / "last.pt")["epoch"] == 2


def test_resume_on_descriptors_of_another_d_says_so_first(tmp_path):
    """Resuming on another dataset of another D said 'the dataset was rebuilt since', and with --allow-mismatch as
    hinted, 'the checkpoint does not fit': the D is named first, with the dataset the run trained on."""
    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    run = main(FAST, data, tmp_path / "run")
    other = save_dataset(make_synthetic(places=200, dim=16), tmp_path / "ds16")
    for allow in (False, True):
        with pytest.raises(CheckpointError) as e:
            main(FAST.replace(epochs=2), other, None, resume=run, allow_mismatch=allow)
        assert str(e.value).startswith(f"the run in {run} trained on D=8 descriptors and dataset ")
        assert ("has D=16: another dataset, or another PCA of it, which the checkpoint does not fit; hint: resume on "
                "the dataset the run trained on") in str(e.value) and "rebuilt since" not in str(e.value)
