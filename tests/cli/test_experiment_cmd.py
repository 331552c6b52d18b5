"""``seqnet experiment``'s options: ``--dataset`` given to an experiment that runs only on the nordland64 data."""

from __future__ import annotations

import pytest

from seqnet.cli import main


@pytest.mark.parametrize("name", ["table-s1", "splits"])
def test_dataset_to_an_experiment_that_takes_none_says_which_do(name, tmp_path, capsys):
    assert main(["experiment", name, "--dataset", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "required" not in err
    assert ("error: table-s1 takes no --dataset: it runs on the nordland64 data only, given by --data (the "
            "nordland64 folder); only table-1, table-3, table-s2 take a seqnet dataset (--dataset)") in err
    assert not (tmp_path / "out").exists()


def test_dataset_to_the_timing_sweep_says_it_reads_no_data(tmp_path, capsys):
    assert main(["experiment", "table-2", "--dataset", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "error: table-2 takes no --dataset: it reads no data; only table-1, table-3" in capsys.readouterr().err
