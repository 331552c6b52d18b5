"""A model's training queries held against the data a command reads (:mod:`seqnet.methods.trained`)."""

import json
import shutil
from types import SimpleNamespace

import pytest

from seqnet.cli import main as cli_main
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.methods.checks import leakage
from seqnet.methods.trained import descriptor_digests, free_hint, names_digest, same_data
from seqnet.sequence.checkpoints import load_model


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A dataset on disk and the S_1 checkpoint trained on its train split (queries 0:119), val on val."""
    tmp = tmp_path_factory.mktemp("trained")
    data = save_dataset(make_synthetic(places=200, dim=8), tmp / "ds")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--out",
                     str(tmp / "run"), "--epochs", "1", "--out-dims", "8", "--n-neg-sample", "50",
                     "--cache-refresh", "40", "--device", "cpu"]) == 0
    return data, tmp / "run" / "best.pt"


def _resplit(data, to, splits):
    """A copy of the dataset directory ``data`` at ``to`` (same descriptor files), its splits rewritten."""
    shutil.copytree(data, to)
    meta = json.loads((to / "dataset.json").read_text())
    meta["splits"] = {k: {"reference": [0, 194], "query": list(v)} for k, v in splits.items()}
    (to / "dataset.json").write_text(json.dumps(meta))
    return to


def test_training_queries_are_found_wherever_the_same_descriptors_are_read(trained, tmp_path):
    """A dataset rebuilt (or copied under another name) with new splits over the same descriptors: its test split
    holds the model's training queries, said from the train range its checkpoint recorded (the dataset's
    current 'train' split said nothing: the model scored its own training queries silently)."""
    data, ckpt = trained
    model = load_model(ckpt)
    assert model.trained_on["train_queries"] == [0, 119] and model.trained_on["query_names"]
    moved = _resplit(data, tmp_path / "other", {"train": (100, 191), "val": (0, 40), "test": (40, 100)})
    said = leakage({"s1": model}, moved, load_dataset(moved), "test")
    assert said == [f"60 of the 60 evaluated queries ('test', 40:100) are training queries of the S_1 model {ckpt} "
                    "('train' when it was trained, 0:119): its results on them are not a test (hint: retrain with "
                    "--train-split / --val-split apart from the test split (40:100), or evaluate queries free of "
                    "the models' training and epoch-selection ones: --split 145:191"
                    " (EvalConfig(split='145:191') in Python))"], said
    assert leakage({"s1": model}, data, load_dataset(data), "test") == []  # correct data: silent


def test_other_descriptors_or_an_old_checkpoint_keep_their_rules(trained, synth_dataset, tmp_path):
    """Other descriptor files at the recorded path say nothing of the recorded range; a checkpoint without the
    range (written before) is held, as before, to the train split of the dataset at its recorded path."""
    data, ckpt = trained
    ds = load_dataset(data)
    model = load_model(ckpt)
    model.trained_on = {**model.trained_on, "dataset_digests": {"query/descriptors.npy": "1:x"}}
    assert same_data(model, data, ds)  # other bits, the same images described alike (a GPU rebuild): the same data
    model.provenance = {**(model.provenance or {}), "id": "another describer"}
    assert not same_data(model, data, ds) and leakage({"s1": model}, data, ds, "train") == []
    old = SimpleNamespace(trained_on={"dataset": str(data), "split": "train", "checkpoint": "r/best.pt"})
    assert "('train', 0:119)" in leakage({"s1": old}, data, ds, "train")[0]
    assert leakage({"s1": old}, tmp_path, ds, "train") == []  # another path: unknown, as before


def test_without_recorded_hashes_the_provenance_and_query_names_identify_the_data(synth_dataset, tmp_path):
    """No descriptor hashes on either side (a dataset made in Python): the same provenance and query names."""
    t = {"dataset": "/gone", "split": "train", "checkpoint": "r/best.pt", "train_queries": [0, 50],
         "query_names": names_digest(synth_dataset.query.names)}
    model = SimpleNamespace(trained_on=t, provenance=synth_dataset.query.provenance)
    assert same_data(model, tmp_path, synth_dataset)
    assert leakage({"s1": model}, tmp_path, synth_dataset, "train")[0].startswith("50 of the")
    model.trained_on = {**t, "query_names": "3:abc"}
    assert not same_data(model, tmp_path, synth_dataset)


def test_the_hint_never_names_the_split_in_use(synth_dataset):
    """The free queries named: test when free and not in use; else the longest free range; else training-free
    only, said (never val when calibrating on val); else retrain. A calibration hint avoids the evaluated split
    too."""
    ds = synth_dataset  # train 0:105, val 105:141, test 141:197 (queries)
    (ta, tb), (va, vb) = ds.ranges("train")["query"], ds.ranges("val")["query"]
    te = ds.ranges("test")["query"]
    assert free_hint(ds, [(ta, tb)], [(va, vb)], "train") == "--split test (EvalConfig(split='test') in Python)"
    assert free_hint(ds, [(ta, te[1])], [], "test").startswith("no range of 20 or more queries")
    hint = free_hint(ds, [(0, 80)], [(80, 141)], "val", "--calibrate-split", [te])
    assert hint == ("--calibrate-split 80:141"
                    " (EvalConfig(calibrate_split='80:141') in Python)"
                    " (free of the models' training queries, though an epoch was chosen on "
                    "some)"), hint
    hint = free_hint(ds, [(0, 141), (150, 197)], [], "val", "--calibrate-split", [(141, 150)])
    assert hint == "no range of 20 or more queries is free of the models' training queries: retrain with " \
        "--train-split / --val-split that leave queries apart for calibration"


def test_the_checkpoint_records_what_identifies_its_training_queries(trained):
    data, ckpt = trained
    t = load_model(ckpt).trained_on
    assert t["dataset_digests"] == descriptor_digests(data)
    assert t["query_names"] == names_digest(load_dataset(data).query.names)


def test_the_calibration_hint_names_queries_free_of_training_not_the_split_in_use(synth_dataset, synth_dir):
    """Calibrating on a val split that holds training queries: the hint was ``--calibrate-split val``, the split in
    use; it names queries apart from training (and from the evaluated split), or says none are."""
    ds = synth_dataset  # queries: train 0:105, val 105:141, test 141:197
    record = {"dataset": str(synth_dir), "split": "0:120", "checkpoint": "r/best.pt", "val_split": "none"}
    said = leakage({"s1": SimpleNamespace(trained_on=record)}, synth_dir, ds, "val", calibration=True,
                   evaluated="test")
    assert said == ["15 of the 36 calibration queries ('val', 105:141) are training queries of the S_1 model "
                    "r/best.pt ('0:120', 0:120): a threshold calibrated on them is optimistic, its promise does not "
                    "hold (hint: --calibrate-split 120:141"
                    " (EvalConfig(calibrate_split='120:141') in Python)"
                    " (queries free of the models' training and epoch-selection "
                    "ones))"], said
    record = {**record, "split": "0:130"}
    said = leakage({"s1": SimpleNamespace(trained_on=record)}, synth_dir, ds, "val", calibration=True,
                   evaluated="test")
    assert said[0].endswith("(hint: no range of 20 or more queries is free of the models' training queries: retrain "
                            "with --train-split / --val-split that leave queries apart for calibration)"), said


def test_leakage_counts_the_queries_kept_by_resample_every(trained, caplog):
    """With ``--resample-every N`` the warnings counted the split's queries before re-sampling ("119 of the 197
    evaluated" when every 2nd was evaluated): they count the kept ones, and say which."""
    import logging

    data, ckpt = trained
    ds = load_dataset(data)
    n, (ta, tb) = len(ds.query), ds.ranges("train")["query"]
    caplog.set_level(logging.WARNING, logger="seqnet")
    assert cli_main(["--threads", "1", "eval", "--dataset", str(data), "--model", str(ckpt), "--method",
                     "single,s1", "--split", "all", "--resample-every", "2", "--device", "cpu"]) == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    kept = range(0, n, 2)
    assert (f"{sum(ta <= q < tb for q in kept)} of the {len(kept)} evaluated queries ('all', every 2nd of 0:{n}) "
            f"are training queries") in said, said
    model = load_model(ckpt)
    for a, b, every in ((0, n, 3), (5, 150, 4), (ta + 1, n, 7)):  # against a loop over the kept queries
        line = leakage({"s1": model}, data, ds, f"{a}:{b}", every=every)[0]
        kept = range(a, b, every)
        assert line.startswith(f"{sum(ta <= q < tb for q in kept)} of the {len(kept)} evaluated queries ('{a}:{b}', "
                               f"every {every}"), line
    assert leakage({"s1": model}, data, ds, "all", every=1)[0].startswith(f"{tb - ta} of the {n} evaluated queries "
                                                                           f"('all', 0:{n})")
