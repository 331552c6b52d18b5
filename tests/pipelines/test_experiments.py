"""Every ``seqnet experiment`` end to end on a tiny range of the shared nordland64 data (one shared
cache: descriptors and models are made once), and the reversed reference."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_data
from report.test_report_html import assert_self_contained

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.data.positives import Positives
from seqnet.data.traverse import Dataset, Traverse
from seqnet.pipelines.experiments import EXPERIMENTS
from seqnet.pipelines.experiments.reverse import reverse_reference

TINY = ["--train-range", "0:120", "--val-range", "130:170", "--test-range", "180:260", "--epochs", "1",
        "--pca-dims", "64", "--threads", "2"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def run(name, out, cache, *extra):
    data = shared_data("nordland64")
    rc = cli_main(["experiment", name, "--data", str(data), "--out", str(out), "--cache", str(cache), *TINY, *extra])
    assert rc == 0
    for f in ("results.json", "results.md", "report.html", "config.json"):
        assert (out / f).is_file(), f
    config = json.loads((out / "config.json").read_text())
    assert config["experiment"] and config["benchmark"]["test_range"] == [180, 260] and config["provenance"]
    assert (out / config["figure"]).stat().st_size > 1000
    return json.loads((out / "results.json").read_text())


def test_reverse(tmp_path, cache, capsys):
    res = run("reverse", tmp_path / "rev", cache)
    r1 = res["recall@1"]
    assert set(r1) == {"val forward", "val reversed", "test forward", "test reversed"}
    # forward SeqMatch on the reference and reverse SeqMatch on the reversed reference are the same sums
    assert r1["test reversed"]["raw+seqmatch-rev"] == pytest.approx(r1["test forward"]["raw+seqmatch"])
    assert r1["test reversed"]["s1+seqmatch-rev"] == pytest.approx(r1["test forward"]["s1+seqmatch"])
    assert r1["test reversed"]["raw+seqmatch-rev"] > r1["test reversed"]["raw+seqmatch"]
    assert "| hvpr-seqnet:s1+seqmatch-rev |" in (tmp_path / "rev" / "results.md").read_text()
    assert_self_contained(tmp_path / "rev" / "report.html", ("experiment", "figure", "results", "matrix", "gallery"))
    assert "R@1 test reversed" in capsys.readouterr().out


def test_longer_sequences(tmp_path, cache):
    res = run("longer-sequences", tmp_path / "long", cache, "--lengths", "3,5,9")
    assert res["lengths"] == [3, 5, 9] and "s1+graph" in res["methods"] and "hvpr-fused" in res["methods"]
    q = res["queries"]
    assert q["test L_m=3"] == q["test L_m=5"] > q["test L_m=9"]  # L = 5 windows limit the first two alike
    assert all(0 <= v <= 1 for col in res["recall@1"].values() for v in col.values())
    assert res["details"]["test L_m=9"]["hvpr"]["queries"] == q["test L_m=9"]


def test_descriptors(tmp_path, cache):
    out = tmp_path / "desc"
    res = run("descriptors", out, cache, "--descriptors", "pixels,gmp", "--cnn-size", "64x32")
    assert set(res["recall@1"]) == {"val pixels", "test pixels", "val gmp", "test gmp"}
    assert "delta-paper" in res["recall@1"]["test gmp"] and "hvpr-fused" in res["recall@1"]["test pixels"]
    assert res["descriptors"]["gmp"]["size"] == [64, 32]
    assert res["provenance"]["gmp"] != res["provenance"]["pixels"]
    assert (cache / "descriptors" / "gmp" / "models" / "seqnet.pt").is_file()  # its own models
    for d in ("pixels", "gmp"):
        assert_self_contained(out / d / "report.html")


def test_tsne(tmp_path, cache, monkeypatch):
    pytest.importorskip("sklearn")
    from seqnet.data.io import load_dataset
    from seqnet.pipelines.experiments import tsne

    seen = []  # the frames each descriptor is computed on
    real = tsne.frame_descriptors
    monkeypatch.setattr(tsne, "frame_descriptors", lambda desc, *a: seen.append(np.array(desc)) or real(desc, *a))
    res = run("tsne", tmp_path / "tsne", cache, "--frames", "50", "--perplexity", "10")
    # the paper's: the first images of the Summer *test* set (places 180:260 here), never train frames (0:120)
    assert res["split"] == "test" and res["first_place"] + res["frame_range"][0] == 180 and res["frames"] == 50
    ds = load_dataset(cache / "dataset")  # the benchmark descriptors' dataset (descriptor_cache)
    a, b = res["frame_range"]
    assert (a, b) == (ds.splits["test"]["reference"][0], ds.splits["test"]["reference"][0] + 50)
    assert len(seen) == 5 and all(np.array_equal(x, ds.reference.descriptors[a:b]) for x in seen)
    rates = res["route_neighbour_rate"]
    assert list(rates) == ["raw", "smoothing", "delta", "S_1", "S_L"]
    assert all(0.0 <= v["descriptor"] <= 1.0 and 0.0 <= v["tsne"] <= 1.0 for v in rates.values())
    assert rates["smoothing"]["descriptor"] > rates["raw"]["descriptor"]  # windows overlap along the route


def test_seeds(tmp_path, cache):
    res = run("seeds", tmp_path / "seeds", cache, "--seeds", "0,1")
    assert res["seeds"] == [0, 1]
    for split in ("val", "test"):
        for m, v in res["recall@1"][split].items():
            per = [res["per_seed"][s][split][m]["recall@1"] for s in ("0", "1")]
            assert v["mean"] == pytest.approx(np.mean(per)) and v["std"] == pytest.approx(np.std(per, ddof=1))
    assert (cache / "seeds" / "seed1" / "models" / "s1.pt").is_file() and not (cache / "seeds" / "seed0").exists()


def test_reverse_reference_is_an_involution():
    rng = np.random.default_rng(0)
    d = rng.standard_normal((10, 3)).astype(np.float32)
    bounds = np.array([[0, 4]] * 4 + [[4, 10]] * 6)
    ref = Traverse(d, np.arange(10.0), names=[f"{i}.png" for i in range(10)], seq_bounds=bounds)
    ds = Dataset(ref, Traverse(d, np.arange(10.0)), radius=1.0,
                 positives=Positives.from_lists([[i] for i in range(10)]))
    rev = reverse_reference(ds)
    assert rev.reference.names[0] == "9.png" and rev.reference.positions[0, 0] == 9.0
    b = rev.reference.seq_bounds  # frames 9..4 were in [4, 10): now 0..5 in [0, 6)
    assert b[:6].tolist() == [[0, 6]] * 6 and b[6:].tolist() == [[6, 10]] * 4
    assert rev.positives.of(0).tolist() == [9]
    back = reverse_reference(rev)
    np.testing.assert_array_equal(back.reference.descriptors, d)
    np.testing.assert_array_equal(back.reference.seq_bounds, bounds)


def test_experiment_table_and_bad_options(tmp_path, capsys):
    assert list(EXPERIMENTS) == ["reverse", "longer-sequences", "descriptors", "tsne", "seeds"]
    with pytest.raises(ConfigError, match="descriptor"):
        EXPERIMENTS["descriptors"].config(descriptors=("sift",))
    rc = cli_main(["experiment", "descriptors", "--data", str(tmp_path), "--out", str(tmp_path / "o"),
                   "--descriptors", "sift"])
    assert rc == 2 and "unknown descriptor 'sift'" in capsys.readouterr().err
    rc = cli_main(["experiment", "nope", "--data", str(tmp_path), "--out", str(tmp_path / "o")])
    assert rc == 2 and "invalid choice" in capsys.readouterr().err
