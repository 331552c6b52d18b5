"""seqnet benchmark timing: a tiny sweep end to end (schema, plot, temporary maps deleted), config and CLI errors."""

from __future__ import annotations

import json
import shutil
import tempfile

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.pipelines.timing import TimingConfig, main
from seqnet.pipelines.timing.synth import Layout, route, window_means

TINY = TimingConfig(sizes=(300,), dims=(16,), queries=3, repeats=1, warmup=1, seq_lens=(3,), top_ks=(4,),
                    indexes=("hnsw",), threads=1)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The tiny sweep, run once from a folder holding a hostile ``seqnet/`` package and ``json.py`` (the
    measuring processes must import neither), into an output folder holding a killed run's leftovers and a
    user's file; the system's temporary folder is watched (the maps go beside the output folder)."""
    root = tmp_path_factory.mktemp("sweep")
    evil, scratch, out = root / "cwd", root / "scratch", root / "out"
    for d in (evil / "seqnet", scratch, out):
        d.mkdir(parents=True)
    for name in ("seqnet/__init__.py", "json.py"):
        (evil / name).write_text(f"open({str(root / 'IMPORTED')!r}, 'a').write({name!r} + '\\n')\n")
    dead = [out / ".results.md.seqnet-abc123.tmp", root / ".out.seqnet-dead1.tmp" / "map-300x16" / "frames.npy"]
    for p in dead:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("left by a killed run")
    (out / "notes.txt").write_text("mine")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tempfile, "tempdir", str(scratch))
        mp.chdir(evil)
        path = main(TINY, out)
    return {"root": root, "out": out, "scratch": scratch, "res": json.loads(path.read_text()), "dead": dead}


def test_tiny_sweep_end_to_end(sweep):
    res, out = sweep["res"], sweep["out"]
    assert {"config", "machine", "seconds", "maps"} <= set(res) and len(res["maps"]) == 1
    e = res["maps"][0]
    assert (e["n_db"], e["dim"], e["queries"]) == (300, 16, 3)
    assert e["peak_rss_bytes"] > 0 and e["build_peak_rss_bytes"] > 0 and e["map_bytes"] > 0
    assert set(e["float16_recall@1"]) == {"float32", "float16"} and "hnsw" in e["index_build_s"]
    methods = {r["method"] for r in e["rows"]}
    assert methods == {"describe_s1", "describe_sl", "knn_single", "knn_shortlist", "seqmatch_all_paper",
                       "seqmatch_all_ours", "seqmatch_topk", "hvpr_exact", "hvpr_hnsw"}
    for r in e["rows"]:
        assert r["per_query_ms"] > 0 and r["per_query_std_ms"] >= 0 and r["comparisons"] >= 0
    rows = {r["method"]: r for r in e["rows"]}
    assert rows["seqmatch_all_paper"]["comparisons"] == 300 * 3 and rows["seqmatch_all_ours"]["comparisons"] == 300
    assert rows["seqmatch_topk"]["comparisons"] == 4 * 3 and 0 <= rows["hvpr_hnsw"]["shortlist_recall"] <= 1
    assert (out / "timing.png").stat().st_size > 1000
    md = (out / "results.md").read_text()
    assert "| | S_1 | S_5 | SeqMatch: All | SeqMatch: Top 20 |" in md and "| ours, paper's way |" in md


def test_the_workers_never_import_from_the_current_folder(sweep):
    """`benchmark timing` started from a folder holding a `seqnet/` package (or a `json.py`): the measuring
    processes import seqnet from where the parent did (python_command), never that code."""
    assert not (sweep["root"] / "IMPORTED").exists()


def test_the_maps_and_a_killed_runs_leftovers_are_gone(sweep):
    """D11: a dead `.results.md.seqnet-*.tmp` in the output folder no longer makes it refused; the working
    folder of a killed run (maps of GBs with --big) is removed by the next run; nothing is left in the system's
    temporary folder or beside the output; the user's file is kept."""
    assert not [p for p in sweep["dead"] if p.exists()] and not (sweep["root"] / ".out.seqnet-dead1.tmp").exists()
    assert not list(sweep["scratch"].iterdir())
    assert sorted(p.name for p in sweep["root"].iterdir()) == ["cwd", "out", "scratch"]
    assert (sweep["out"] / "notes.txt").read_text() == "mine"


def entries(sweep, sizes):
    """Measured entries for maps of ``sizes`` (the sweep's, relabelled): what ``measure`` would return."""
    return [{**sweep["res"]["maps"][0], "n_db": n} for n in sizes]


def test_a_killed_run_leaves_its_three_outputs_of_one_run(sweep, tmp_path, monkeypatch):
    """D8: results.json, results.md and timing.png always come from one run, at any kill point (a new
    results.json beside an old timing.png used to be left)."""
    import hashlib

    from conftest import each_crash_point, restorer

    from seqnet.pipelines.timing import run

    out = tmp_path / "t"
    def digests():
        return [hashlib.sha256((out / f).read_bytes()).hexdigest() for f in ("timing.png", "results.md")]

    figures = {}
    for sizes in ((300,), (300, 600)):
        monkeypatch.setattr(run, "measure", lambda *a, sizes=sizes: entries(sweep, sizes))
        main(TINY, out)
        figures[len(sizes)] = digests()
    assert figures[1][0] != figures[2][0] and figures[1][1] != figures[2][1]
    saved = tmp_path / "saved"
    shutil.copytree(out, saved)

    restore = restorer(saved, out)

    def check():
        n = len(json.loads((out / "results.json").read_text())["maps"])
        assert digests() == figures[n]

    monkeypatch.setattr(run, "measure", lambda *a: entries(sweep, (300,)))
    assert each_crash_point(restore, main, TINY, out, check=check, modes=("after",)) >= 3


def test_only_a_timing_runs_outputs_are_replaced(sweep, tmp_path, monkeypatch, capsys):
    from seqnet.pipelines.timing import run
    from seqnet.security.ownership import write_manifest

    monkeypatch.setattr(run, "measure", lambda *a: entries(sweep, (300,)))
    out = tmp_path / "t"
    out.mkdir()
    (out / "results.md").write_text("my own notes")
    for extra in ([], ["--overwrite"]):
        assert cli(["benchmark", "timing", "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "results.md was not written by seqnet" in err[0], err
    assert (out / "results.md").read_text() == "my own notes"
    # what an older seqnet's timing wrote (its manifest, kind "timing") is its own: replaced
    for f in run.OUT_FILES:
        (out / f).write_text("an older run's")
    write_manifest(out, "timing", [out / f for f in run.OUT_FILES])
    assert cli(["-q", "benchmark", "timing", "--out", str(out)]) == 0
    assert json.loads((out / "results.json").read_text())["maps"][0]["n_db"] == 300
    # another command's results in that folder: refused unless --overwrite
    monkeypatch.setattr(run, "measure", lambda *a: entries(sweep, (300,)))
    assert run.main(TINY, out, kind="experiment compute-time", overwrite=True)
    capsys.readouterr()
    assert cli(["benchmark", "timing", "--out", str(out)]) == 2
    assert "written by `seqnet experiment compute-time`" in capsys.readouterr().err
    assert cli(["-q", "benchmark", "timing", "--out", str(out), "--overwrite"]) == 0


def test_synthetic_route_is_smooth_and_unit(rng):
    frames = route(200, 32, rng)
    np.testing.assert_allclose(np.linalg.norm(frames, axis=1), 1, rtol=1e-5)
    near = (frames[1:] * frames[:-1]).sum(1).mean()
    far = (frames[100:] * frames[:100]).sum(1).mean()
    assert near > 0.8 and abs(far) < 0.2
    lay = Layout(200, 5)
    means = window_means(frames, lay.starts(3, lay.items), 3)
    want = frames[lay.items[0] - 1 : lay.items[0] + 2].mean(0)
    np.testing.assert_allclose(means[0], want / np.linalg.norm(want), rtol=1e-5)


def test_config_and_cli_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match="max_elements"):
        TimingConfig(sizes=(1000,), dims=(64,), max_elements=10)
    with pytest.raises(ConfigError, match="ANN index kind"):
        TimingConfig(indexes=("annoy",))
    for argv, pattern in ((["--sizes", "50"], "sizes must be an integer >= 100"),
                          (["--dataset", str(tmp_path)], "needs the models of its map"),
                          (["--indexes", "lsh"], "unknown ANN index kind")):
        capsys.readouterr()
        assert cli(["benchmark", "timing", "--out", str(tmp_path / "o"), *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and pattern in err[0], err


def test_paper_style_seqmatch_and_exact_search_equal_the_library(rng):
    import torch

    from seqnet.matching.seqmatch import seqmatch_topk
    from seqnet.pipelines.timing.measure import paper_seqmatch
    from seqnet.search.knn import ExactIndex, knn_torch

    ref = rng.standard_normal((500, 8)).astype(np.float32)
    q = rng.standard_normal((30, 8)).astype(np.float32)
    search = ExactIndex(ref.astype(np.float16), "cpu", 2**20, col_block=64)
    want = knn_torch(q, ref.astype(np.float16), 7, col_block=64)
    np.testing.assert_array_equal(search.search(q, 7)[1], want[1])
    r_starts = np.arange(0, 496, 3)
    got = paper_seqmatch(search, torch.from_numpy(q[4:9]), torch.as_tensor(r_starts), 5).numpy()
    np.testing.assert_array_equal(got, seqmatch_topk(q, ref.astype(np.float16), 5, 5, np.array([4]), r_starts)[1][0])


def test_a_datasets_map_is_timed_with_its_queries(synth_dataset, synth_dir, tmp_path):
    from seqnet.maps import MapConfig

    conf = TINY.replace(seq_lens=(4,), seq_len=4, indexes=(), float16_recall=False)
    mconf = MapConfig(shortlist="delta", rerank="raw+seqmatch")
    res = json.loads(main(conf, tmp_path / "out", synth_dir, map_config=mconf).read_text())
    e = res["maps"][0]
    assert e["n_db"] == len(synth_dataset.split("test").reference) and res["config"]["dataset"] == str(synth_dir)
    assert {r["method"] for r in e["rows"]} >= {"knn_shortlist", "seqmatch_all_paper", "hvpr_exact"}


def test_the_paper_table_times_s1_and_s5_as_extraction_only():
    """Table II's S_1 / S_5 are descriptor extraction only (the paper's protocol); the end-to-end row adds
    the k-NN, and whole-map SeqMatch end to end is the row-reusing one; the paper's layout (its columns,
    its row first), a sum's std from the parts' variances."""
    from seqnet.pipelines.timing.report import paper_table

    ms = {"describe_s1": 1.0, "knn_single": 10.0, "describe_sl": 2.0, "knn_shortlist": 20.0,
          "seqmatch_all_paper": 300.0, "seqmatch_all_ours": 30.0, "seqmatch_topk": 0.5}
    rows = [{"method": m, "per_query_ms": v, "per_query_std_ms": 0.3 if m == "describe_s1" else 0.4,
             "per_query_cpu_ms": v, "seq_len": 5 if m.startswith("seqmatch") else None,
             "top_k": 20 if m == "seqmatch_topk" else None} for m, v in ms.items()]
    lines = paper_table({"rows": rows, "n_db": 300, "dim": 8}, 5, 20).splitlines()
    table = {line.split(" | ")[0].strip("| "): [c.strip(" |") for c in line.split(" | ")[1:]] for line in lines
             if line.startswith("| ") and "---" not in line}
    assert table[""] == ["S_1", "S_5", "SeqMatch: All", "SeqMatch: Top 20"]
    assert table["paper (GTX 1080 Ti)"] == ["22.1 ± 13.0", "24.2 ± 11.9", "1449.9 ± 120.5", "1.8 ± 0.2"]
    assert table["ours, paper's way"] == ["1.00 ± 0.30", "2.00 ± 0.40", "300.00 ± 0.40", "0.50 ± 0.40"]
    assert table["ours, end to end"] == ["11.00 ± 0.50", "22.00 ± 0.57", "30.00 ± 0.40", "0.50 ± 0.40"]
