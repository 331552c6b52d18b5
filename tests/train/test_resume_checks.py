"""Resuming a run: on the descriptors it was trained on only, and only to a later epoch."""

from __future__ import annotations

import pytest

from seqnet.cli import main as cli_main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic

ARGS = ["--seq-len", "3", "--w", "2", "--out-dims", "8", "--optimizer", "adam", "--lr", "1e-2",
        "--n-neg-sample", "50", "--cache-refresh", "40", "--device", "cpu", "--val-split", "none"]


@pytest.fixture(scope="module")
def run2(tmp_path_factory):
    """A dataset, the same rebuilt with other descriptors (another seed), and a two-epoch run of the first."""
    root = tmp_path_factory.mktemp("resume")
    data = save_dataset(make_synthetic(places=120, dim=8), root / "ds")
    save_dataset(make_synthetic(places=120, dim=8, seed=1), root / "rebuilt")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--out", str(root / "run"),
                     "--epochs", "2", *ARGS]) == 0
    return root


def _err(capsys, argv, quiet=True):
    capsys.readouterr()
    rc = cli_main([*(["-q"] if quiet else []), "--threads", "1", *argv])
    return rc, capsys.readouterr().err.strip().splitlines()


def test_resume_on_rebuilt_descriptors_is_refused(run2, capsys):
    """The dataset rebuilt with other descriptors (same D): one line naming the difference, the run untouched."""
    last = (run2 / "run" / "last.pt").read_bytes()
    rc, err = _err(capsys, ["train", "--resume", str(run2 / "run"), "--dataset", str(run2 / "rebuilt"),
                            "--epochs", "3"])
    assert rc == 2 and len(err) == 1, err
    assert f"the descriptors the run in {run2 / 'run'} was trained on and the descriptors of dataset" in err[0]
    assert "seed: 0 vs 1" in err[0] and "Traceback" not in err[0]
    assert (run2 / "run" / "last.pt").read_bytes() == last


def test_resume_to_no_more_epochs_is_refused(run2, capsys):
    """--epochs is the total: not above the epochs done, one line saying so and what to give."""
    for epochs in ("1", "2"):
        rc, err = _err(capsys, ["train", "--resume", str(run2 / "run"), "--epochs", epochs])
        assert rc == 2 and err == [f"seqnet train: error: {run2 / 'run'} is already trained to epoch 2; --epochs "
                                   f"{epochs} is the total number of epochs (not more to run): give --epochs 3 or "
                                   "more"], err
    rc, err = _err(capsys, ["train", "--resume", str(run2 / "run")])  # its own 2 epochs: done
    assert rc == 2 and "already trained to epoch 2; --epochs 2 is the total" in err[0]


def test_joint_resume_to_no_more_epochs_is_refused_and_a_finished_role_left(run2, capsys):
    joint = run2 / "joint"
    argv = ["train", "--joint", "--dataset", str(run2 / "ds"), "--out", str(joint), "--epochs", "1", *ARGS]
    assert _err(capsys, argv)[0] == 0
    rc, err = _err(capsys, ["train", "--resume", str(joint), "--epochs", "1"])
    assert rc == 2 and len(err) == 1 and "/s1 is already trained to epoch 1; --epochs 1 is the total" in err[0], err
    for name in ("last.pt", "best.pt"):  # S_1 killed before its first epoch: only it has epochs left
        (joint / "s1" / name).unlink()
    rc, err = _err(capsys, ["train", "--resume", str(joint), "--epochs", "1"], quiet=False)
    assert rc == 0 and f"{joint / 'seqnet'} is already trained to epoch 1 of 1; left as it is" in err, err
    assert (joint / "s1" / "last.pt").is_file()


def test_resume_on_other_descriptor_files_of_the_same_making_is_refused(run2, capsys):
    """Descriptors made alike (same provenance) but other files (a rebuild on other images): the hashes seqnet
    recorded in dataset.json name the change; --allow-mismatch goes on with a warning."""
    import dataclasses

    ds = make_synthetic(places=120, dim=8)
    other = dataclasses.replace(ds.query, descriptors=ds.query.descriptors[::-1].copy())
    data = save_dataset(dataclasses.replace(ds, query=other), run2 / "same-making")
    argv = ["train", "--resume", str(run2 / "run"), "--dataset", str(data), "--epochs", "3"]
    rc, err = _err(capsys, argv)
    assert rc == 2 and len(err) == 1, err
    assert (f"the descriptors of dataset 'synthetic' are not those the run in {run2 / 'run'} was trained on "
            "(query/descriptors.npy changed: the dataset was rebuilt since)") in err[0]
