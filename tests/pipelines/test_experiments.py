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
    res = run("table-3", tmp_path / "rev", cache)  # the paper's table name runs the same experiment
    r1 = res["recall@1"]
    assert set(r1) == {"val forward", "val reversed", "test forward", "test reversed"}
    # forward SeqMatch on the reference and reverse SeqMatch on the reversed reference are the same sums
    assert r1["test reversed"]["raw+seqmatch-rev"] == pytest.approx(r1["test forward"]["raw+seqmatch"])
    assert r1["test reversed"]["s1+seqmatch-rev"] == pytest.approx(r1["test forward"]["s1+seqmatch"])
    assert r1["test reversed"]["raw+seqmatch-rev"] > r1["test reversed"]["raw+seqmatch"]
    md = (tmp_path / "rev" / "results.md").read_text()
    assert "| hvpr-seqnet:s1+seqmatch-rev |" in md and "**Table III — Reverse Traverse" in md
    raw = next(line for line in md.splitlines() if line.startswith("| Raw + SeqMatch |"))
    rev = res["details"]["test reversed"]
    assert raw.split(" | ")[2] == "/".join(f"{rev['raw+seqmatch'][f'recall@{k}']:.3f}" for k in (1, 5, 20))
    assert raw.split(" | ")[3] == "/".join(f"{rev['raw+seqmatch-rev'][f'recall@{k}']:.3f}" for k in (1, 5, 20))
    assert_self_contained(tmp_path / "rev" / "report.html", ("experiment", "figure", "results", "matrix", "gallery"))
    assert "R@1 test reversed" in capsys.readouterr().out


def test_longer_sequences(tmp_path, cache):
    res = run("longer-sequences", tmp_path / "long", cache, "--lengths", "3,5,9")
    assert res["lengths"] == [3, 5, 9] and "s1+graph" in res["methods"] and "hvpr-fused" in res["methods"]
    q = res["queries"]
    assert q["test L_m=3"] == q["test L_m=5"] > q["test L_m=9"]  # L = 5 windows limit the first two alike
    assert all(0 <= v <= 1 for col in res["recall@1"].values() for v in col.values())
    assert res["details"]["test L_m=9"]["hvpr"]["queries"] == q["test L_m=9"]
    gism = paper_row((tmp_path / "long" / "results.md").read_text(), "GISM")
    graph = res["details"]["test L_m=9"]["s1+graph"]
    assert gism[1] == "`s1+graph`" and gism[4] == "/".join(f"{graph[f'recall@{k}']:.3f}" for k in (1, 5, 20))
    assert gism[5:] == ["0.65/-/-", "0.68/-/-", "0.73/-/-"]


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
    header = next(line for line in (out / "results.md").read_text().splitlines() if line.startswith("| paper's row"))
    assert header == "| paper's row | seqnet | ours: pixels | ours: gmp | paper: NetVLAD | paper: GMP |"


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


def paper_row(md: str, label: str) -> list[str]:
    """The cells of the paper-layout row ``label`` of ``results.md``."""
    return next(line for line in md.splitlines() if line.startswith(f"| {label} |")).strip("| ").split(" | ")


def test_comparison(tmp_path, cache):
    res = run("table-1", tmp_path / "t1", cache)
    assert res["paper_table"] == "I" and res["recall_denominator"] == "positives"
    test = res["details"]["test"]
    assert {"single", "delta-paper", "s1+graph", "s1+grh-dh", "s1+grh", "hvpr-delta-paper", "hvpr",
            "hvpr-fused"} <= set(test)
    md = (tmp_path / "t1" / "results.md").read_text()
    hvpr = paper_row(md, "HVPR (S_5 to S_1)")
    assert hvpr[1].split(" [learned, below model-free ")[0] == "`hvpr`"  # marked when below raw+seqmatch
    assert hvpr[3] == "/".join(f"{test['hvpr'][f'recall@{k}']:.3f}" for k in (1, 5, 20))
    assert hvpr[4:] == ["0.72/0.82/0.88", "0.29/0.40/0.55"]  # the paper's, as printed
    assert paper_row(md, "AP-GeM")[1:4] == ["–", "–", "–"]  # not a descriptor here
    assert paper_row(md, "seqnet: hvpr-fused")[4:] == ["-", "-"]
    command = md[md.index("    seqnet eval --dataset DIR"):].split()  # the same rows on a user's dataset
    methods = command[command.index("--method") + 1].split(",")
    assert methods == list(res["methods"]) and "hvpr-delta-paper" in methods
    every = run("comparison", tmp_path / "all", cache, "--recall-denominator", "all")
    assert every["recall_denominator"] == "all"
    assert "denominator (ours): all" in (tmp_path / "all" / "results.md").read_text()
    for m, r in every["details"]["test"].items():  # the same ranking over more queries: never higher
        assert r["recall@1"] <= test[m]["recall@1"] + 1e-12


def test_splits(tmp_path, cache):
    res = run("table-s1", tmp_path / "s1", cache)
    assert res["sizes"] == {"train": {"reference": 120, "query": 120, "places": [0, 120]},
                            "val": {"reference": 40, "query": 40, "places": [130, 170]},
                            "test": {"reference": 80, "query": 80, "places": [180, 260]}}
    md = (tmp_path / "s1" / "results.md").read_text()
    assert paper_row(md, "Test") == ["Test", "`test`", "80 / 80", "1574 / 1576", "2858 / 2770", "3000 / 3000",
                                      "33000 / 18000"]


def test_compute_time(tmp_path, monkeypatch):
    from seqnet.pipelines.experiments import compute_time
    from seqnet.pipelines.timing import TimingConfig

    asked = []
    real = compute_time.timing_main

    def tiny(conf, out):  # the paper's map size is asked for; a tiny one is timed
        asked.append(conf)
        return real(TimingConfig(sizes=(300,), dims=(16,), queries=conf.queries, repeats=1, warmup=1, indexes=(),
                                 float16_recall=False, threads=1), out)

    monkeypatch.setattr(compute_time, "timing_main", tiny)
    out = tmp_path / "t2"
    assert cli_main(["experiment", "table-2", "--out", str(out), "--queries", "3"]) == 0
    assert asked[0].sizes == (14000,) and asked[0].dims == (4096,) and asked[0].queries == 3
    res = json.loads((out / "results.json").read_text())
    assert res["paper_table"] == "II" and set(res["ms"]) == {"paper's way", "end to end"}
    timing = json.loads((out / "timing" / "results.json").read_text())["maps"][0]["rows"]
    s1 = next(r for r in timing if r["method"] == "describe_s1")
    assert res["ms"]["paper's way"]["S_1"][0] == pytest.approx(s1["per_query_ms"])
    md = (out / "results.md").read_text()
    assert "| paper (GTX 1080 Ti) | 22.1 ± 13.0 | 24.2 ± 11.9 | 1449.9 ± 120.5 | 1.8 ± 0.2 |" in md
    assert (out / "compute_time.png").stat().st_size > 1000 and (out / "report.html").is_file()


def test_tables(tmp_path, cache, capsys):
    data, out = shared_data("nordland64"), tmp_path / "tables"
    rc = cli_main(["experiment", "tables", "--data", str(data), "--out", str(out), "--cache", str(cache), *TINY,
                   "--tables", "S1,III"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert list(res["tables"]) == ["S1", "III"] and res["tables"]["III"]["folder"] == "table-3"
    md = (out / "results.md").read_text()
    assert md.index("## S1: Data splits (paper: Table S1), Nordland64 (`seqnet experiment table-s1`, table-s1/)") < \
        md.index("## III: Reverse traverse")
    assert "**Table S1 — Data Splits" in md and "**Table III — Reverse Traverse" in md
    assert (out / "table-3" / "results.md").read_text().split("\n", 1)[1].lstrip("\n") in md.replace("\n## ", "\n# ")
    assert "results in" in capsys.readouterr().out
    rc = cli_main(["experiment", "tables", "--data", str(data), "--out", str(out), "--tables", "IV"])
    assert rc == 2 and "unknown paper table 'IV'" in capsys.readouterr().err


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
    assert list(EXPERIMENTS) == ["comparison", "compute-time", "reverse", "splits", "longer-sequences",
                                 "descriptors", "tsne", "seeds", "tables"]
    assert [e.alias for e in EXPERIMENTS.values()] == ["table-1", "table-2", "table-3", "table-s1", "table-s2",
                                                      "table-s3", None, None, None]
    with pytest.raises(ConfigError, match="descriptor"):
        EXPERIMENTS["descriptors"].config(descriptors=("sift",))
    rc = cli_main(["experiment", "descriptors", "--data", str(tmp_path), "--out", str(tmp_path / "o"),
                   "--descriptors", "sift"])
    assert rc == 2 and "unknown descriptor 'sift'" in capsys.readouterr().err
    rc = cli_main(["experiment", "nope", "--data", str(tmp_path), "--out", str(tmp_path / "o")])
    assert rc == 2 and "invalid choice" in capsys.readouterr().err


def test_the_evaluation_tables_run_on_a_users_dataset(synth_dir, synth_dataset, map_models, tmp_path, capsys):
    """Tables I, III and S2 on any seqnet dataset with its models (--dataset, --model): its val and test splits;
    rows whose models are missing show –; exactly one of --data / --dataset."""
    from seqnet.eval.evaluate import EvalConfig, evaluate
    from seqnet.sequence.checkpoints import load_models

    sl, s1 = (str(p) for p in map_models)
    out = tmp_path / "t1"
    assert cli_main(["experiment", "table-1", "--dataset", str(synth_dir), "--model", sl, "--model", s1,
                     "--out", str(out), "--threads", "1"]) == 0
    res = json.loads((out / "results.json").read_text())
    assert set(res["details"]) == {"val", "test"}
    ref = evaluate(synth_dataset.split("test"), EvalConfig(methods=("hvpr", "s1+seqmatch"), seq_len=5, ks=(1, 5, 20)),
                   load_models(map_models))
    for m in ("hvpr", "s1+seqmatch"):  # what `seqnet eval` gives on the same split
        assert res["details"]["test"][m]["recall@1"] == ref.results["methods"][m]["recall@1"]
    md = (out / "results.md").read_text()
    assert "| ours: synthetic val | ours: synthetic test |" in md.replace(f"{synth_dataset.name} ", "synthetic ")
    only_sl = tmp_path / "sl-only"
    assert cli_main(["experiment", "table-1", "--dataset", str(synth_dir), "--model", sl, "--out", str(only_sl)]) == 0
    md = (only_sl / "results.md").read_text()
    assert paper_row(md, "SeqNet (S_1)")[2:4] == ["–", "–"] and paper_row(md, "SeqNet (S_5)")[2] != "–"
    for name in ("table-3", "table-s2"):
        assert cli_main(["experiment", name, "--dataset", str(synth_dir), "--model", sl, "--model", s1,
                         "--out", str(tmp_path / name)] + (["--lengths", "3,5"] if name == "table-s2" else [])) == 0
        assert (tmp_path / name / "report.html").is_file()
    capsys.readouterr()
    for extra in ([], ["--data", str(tmp_path), "--dataset", str(synth_dir)]):
        assert cli_main(["experiment", "table-1", "--out", str(tmp_path / "x"), *extra]) == 2
        assert "give the nordland64 folder (--data) or a seqnet dataset" in capsys.readouterr().err


def test_a_killed_experiment_leaves_its_outputs_of_one_run(tmp_path, cache):
    """D8: results.json, results.md, the figure, report.html and config.json always come from one run, whatever
    the kill point (new results.* used to sit beside an old figure); a user's file in the folder is kept."""
    import hashlib
    import shutil

    from conftest import each_crash_point, restorer

    from seqnet.pipelines.experiments.splits import SplitsConfig

    data, out = shared_data("nordland64"), tmp_path / "out"
    exp = EXPERIMENTS["splits"]
    ranges = {"a": (180, 260), "b": (180, 250)}
    confs = {k: SplitsConfig().replace(benchmark=_tiny_benchmark().replace(test_range=r)) for k, r in ranges.items()}
    caches = {"a": cache, "b": tmp_path / "cache-b"}

    def digests():
        return [hashlib.sha256((out / f).read_bytes()).hexdigest() for f in ("splits.png", "results.md")]

    made = {}
    for k in ("b", "a"):
        exp.run(confs[k], data, out, caches[k])
        made[k] = digests()
    assert made["a"] != made["b"]
    (out / "notes.txt").write_text("mine")
    saved = tmp_path / "saved"
    shutil.copytree(out, saved)

    restore = restorer(saved, out)

    def check():
        test = json.loads((out / "results.json").read_text())["sizes"]["test"]["places"]
        assert digests() == made["a" if test[1] == 260 else "b"]
        assert json.loads((out / "config.json").read_text())["benchmark"]["test_range"] == test
        assert (out / "notes.txt").read_text() == "mine"

    assert each_crash_point(restore, exp.run, confs["b"], data, out, caches["b"], check=check,
                            modes=("after",)) >= 3


def _tiny_benchmark():
    from seqnet.cli import build_parser
    from seqnet.cli.experiment_cmd import experiment_config

    argv = ["experiment", "splits", "--data", "D", "--out", "O", *TINY]
    return experiment_config(build_parser(argv).parse_args(argv)).benchmark


def test_an_experiment_replaces_only_its_own_outputs(tmp_path, cache, capsys):
    """D6/D8: a user's file in place of an output is refused before any work, even with --overwrite; another
    experiment's outputs only with --overwrite; the user's other files are kept."""
    data, out = shared_data("nordland64"), tmp_path / "o"
    out.mkdir()
    (out / "results.md").write_text("my own notes")
    (out / "other.txt").write_text("mine")
    argv = ["experiment", "table-s1", "--data", str(data), "--out", str(out), "--cache", str(cache), *TINY]
    for extra in ([], ["--overwrite"]):
        assert cli_main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "results.md was not written by seqnet" in err[0], err
    assert (out / "results.md").read_text() == "my own notes" and not (out / "results.json").exists()
    (out / "results.md").unlink()
    assert cli_main(["-q", *argv]) == 0
    assert cli_main(["-q", *argv]) == 0  # its own outputs: replaced
    capsys.readouterr()
    other = ["experiment", "table-s2", *argv[2:], "--lengths", "5"]
    assert cli_main(other) == 2  # another experiment's results.json
    err = capsys.readouterr().err
    assert "written by `seqnet experiment splits`, not by `seqnet experiment longer-sequences`" in err
    assert cli_main(["-q", *other, "--overwrite"]) == 0
    assert json.loads((out / "results.json").read_text())["experiment"] == "longer-sequences"
    assert (out / "other.txt").read_text() == "mine" and (out / "splits.png").is_file()  # not its output


def test_tables_holds_its_folders_lock(tmp_path, cache, capsys):
    import fcntl
    import os

    from seqnet.security.locks import lock_file

    data, out = shared_data("nordland64"), tmp_path / "tables"
    holder = os.open(lock_file(out.absolute()), os.O_RDWR | os.O_CREAT)
    fcntl.flock(holder, fcntl.LOCK_EX)  # another seqnet process writing OUT
    try:
        rc = cli_main(["experiment", "tables", "--data", str(data), "--out", str(out), "--cache", str(cache), *TINY,
                       "--tables", "S1"])
    finally:
        os.close(holder)
    assert rc != 0 and "is in use by another seqnet process" in capsys.readouterr().err
    assert not out.exists()


def test_an_experiment_marks_learned_methods_below_model_free_and_says_its_ground_truth(
        synth_dataset, map_models, tmp_path, capsys):
    """table-1 on a user's dataset with explicit positives: results.json has eval's ``learned_below_baseline`` (each
    entry naming its evaluation), results.md marks each such row and lists the notes, and its header names the
    explicit positives, not a radius."""
    import dataclasses

    from seqnet.data.io import save_dataset
    from seqnet.report.guidance import learned_below_baseline

    d = np.linalg.norm(synth_dataset.query.positions[:, None] - synth_dataset.reference.positions[None], axis=-1)
    ds = dataclasses.replace(synth_dataset, positives=Positives.from_lists([np.flatnonzero(r <= 3.0) for r in d]))
    assert synth_dataset.positives is None  # a copy: the shared fixture stays as it is for later tests
    save_dataset(ds, tmp_path / "pos")
    out = tmp_path / "t1"
    sl, s1 = (str(p) for p in map_models)  # random models: below the model-free methods
    assert cli_main(["experiment", "table-1", "--dataset", str(tmp_path / "pos"), "--model", sl, "--model", s1,
                     "--out", str(out), "--threads", "1"]) == 0
    res = json.loads((out / "results.json").read_text())
    md = (out / "results.md").read_text()
    assert "explicit positives (a hit is one of the query's positives)" in md.split("\n\n")[1]
    assert "radius" not in md.split("\n\n")[1]
    notes = res["learned_below_baseline"]
    assert notes and {n["evaluation"] for n in notes} <= {"val", "test"}
    assert all(set(n) >= {"learned", "baseline", "learned_r1", "baseline_r1", "causes", "text"} for n in notes)
    details = res["details"]["test"]  # the same findings as the test evaluation's own results give
    expected = [(n.learned, n.baseline) for n in learned_below_baseline({"methods": details})]
    assert [(n["learned"], n["baseline"]) for n in notes if n["evaluation"] == "test"] == expected
    for n in notes:
        row = next(line for line in md.splitlines() if f"| `{n['learned']}` [" in line)
        where = row.split(f" {n['baseline']} (", 1)[1].split(")")[0]  # its evaluations: "val, test"
        assert "[learned, below model-free " in row and n["evaluation"] in where.split(", ")
        assert f"{n['learned']} (R@1 {n['learned_r1']:.3f}) is below the model-free {n['baseline']}" in md
    assert "Learned methods below their model-free counterparts (test):" in md
    assert "Learned methods below their model-free counterparts" in capsys.readouterr().out  # the CLI prints it
