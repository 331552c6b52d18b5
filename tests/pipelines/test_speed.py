"""Variable-speed query traverses for the Nordland64 benchmark (frames dropped or repeated, positions kept)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_data

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.data.traverse import Dataset, Traverse
from seqnet.pipelines.nordland64 import Nordland64Config
from seqnet.pipelines.nordland64.config import VARIABLE_SPEED_METHODS
from seqnet.pipelines.nordland64.speed import (
    resample_indices,
    resample_traverse,
    speed_profile,
    variable_speed,
)


def test_constant_speeds():
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(resample_indices(50, (1, 1), rng), np.arange(50))
    np.testing.assert_array_equal(resample_indices(9, (2, 2), rng), [0, 2, 4, 6, 8])
    np.testing.assert_array_equal(resample_indices(4, (0.5, 0.5), rng), [0, 1, 1, 2, 2, 3, 3])


def test_profile_is_smooth_bounded_and_seeded():
    v = speed_profile(2000, (0.5, 2.0), np.random.default_rng(1), period=40)
    assert v.min() >= 0.5 and v.max() <= 2.0 and v.max() > 1.6 and v.min() < 0.65
    assert np.abs(np.diff(v)).max() < 1.5 * np.pi / 80  # cosine steps between knots at most 1.5 apart
    again = speed_profile(2000, (0.5, 2.0), np.random.default_rng(1), period=40)
    np.testing.assert_array_equal(v, again)
    idx = resample_indices(800, (0.5, 2.0), np.random.default_rng(1))
    steps = np.diff(idx)
    assert idx[0] == 0 and idx[-1] >= 797 and steps.min() >= 0 and steps.max() <= 2
    assert (steps == 0).any() and (steps == 2).any()  # both repeated and dropped frames


def test_resample_keeps_frames_positions_and_bounds():
    desc = (np.arange(60, dtype=np.float32)[:, None] + 1) * np.ones((1, 3), np.float32)  # row i holds i + 1
    bounds = np.array([[0, 20]] * 20 + [[20, 60]] * 40)
    t = Traverse(desc, np.arange(60) / 10.0, names=[f"f{i}" for i in range(60)], seq_bounds=bounds)
    r = resample_traverse(t, (0.5, 2.0), 3)
    src = r.descriptors[:, 0].astype(int) - 1
    np.testing.assert_allclose(r.positions[:, 0], src / 10.0)
    assert r.names == [f"f{i}" for i in src]
    first = r.seq_bounds[0, 1]
    assert src[:first].max() < 20 <= src[first] and src[first] == 20 and r.seq_bounds[-1].tolist() == [first, len(r)]
    ds = Dataset(t, t, 1.0)
    assert variable_speed(ds, None, 0) is ds
    assert len(variable_speed(ds, (1.0, 1.0), 0).query) == 60


def test_config_and_flag(tmp_path, capsys):
    conf = Nordland64Config(query_speed=[0.5, 2])
    n = len(VARIABLE_SPEED_METHODS)
    assert conf.query_speed == (0.5, 2.0) and conf.eval_config().methods[-n:] == VARIABLE_SPEED_METHODS
    assert Nordland64Config.from_dict(conf.to_dict()) == conf
    assert Nordland64Config().eval_config().methods == Nordland64Config().methods
    with pytest.raises(ConfigError, match="A <= B"):
        Nordland64Config(query_speed=(2, 0.5))
    assert cli_main(["benchmark", "nordland64", "--data", str(tmp_path), "--out", str(tmp_path / "o"),
                     "--query-speed", "2"]) == 2
    assert "expected A:B" in capsys.readouterr().err


TINY = ["--train-range", "0:80", "--val-range", "90:130", "--test-range", "140:220", "--epochs", "1", "--pca-dims",
        "32"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny variable-speed benchmark run (its descriptor and model caches serve the longer-sequence test)."""
    data = shared_data("nordland64")
    out = tmp_path_factory.mktemp("n64") / "b"
    assert cli_main(["benchmark", "nordland64", "--data", str(data), "--out", str(out), *TINY, "--query-speed",
                     "0.5:2", "--device", "cpu", "-q", "--descriptor", "pixels"]) == 0  # longer_sequences' descriptor
    return data, out


def test_tiny_variable_speed_benchmark(tiny_run):
    _, out = tiny_run
    res = json.loads((out / "results.json").read_text())
    assert set(VARIABLE_SPEED_METHODS) <= set(res["methods"]) and res["config"]["benchmark"]["query_speed"] == [0.5, 2]
    assert res["methods"]["raw+seqmatch"]["queries"] != 76  # not the 80 places of the filmed speed
    md = (out / "results.md").read_text()
    assert "0.5–2× the reference speed" in md and "| AUC | R@100P |" in md
    assert (out / "pr_curve.png").stat().st_size > 1000


def test_tiny_longer_sequences(tiny_run):
    from seqnet.pipelines.nordland64 import longer_sequences

    data, out = tiny_run
    conf = Nordland64Config().replace(train_range=(0, 80), val_range=(90, 130), test_range=(140, 220), pca_dims=32,
                                      train={"epochs": 1}, train_s1={"epochs": 1}, device="cpu")
    models = (out / "models" / "seqnet.pt").stat().st_mtime
    path = longer_sequences(conf, data, out, lengths=(3, 8), methods=("hvpr", "s1+graph"))
    assert (out / "models" / "seqnet.pt").stat().st_mtime == models  # the benchmark's models, reused
    rec = json.loads(path.read_text())
    assert list(rec["results"]) == ["val", "test"] and list(rec["results"]["test"]) == ["3", "8"]
    test = rec["results"]["test"]
    assert test["8"]["hvpr"]["method"]["match_len"] == 8 and test["8"]["s1+graph"]["queries"] == 80 - 7
    md = (out / "longer.md").read_text()
    assert "| method | L_m=3 | L_m=8 |" in md and "| s1+graph |" in md and "test 140:220, AUC" in md
