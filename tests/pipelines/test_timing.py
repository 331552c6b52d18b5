"""seqnet benchmark timing: a tiny sweep end to end (schema, plot, temporary maps deleted), config and CLI errors."""

from __future__ import annotations

import json
import tempfile

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.pipelines.timing import TimingConfig, main
from seqnet.pipelines.timing.synth import Layout, route, window_means

TINY = TimingConfig(sizes=(300,), dims=(16,), queries=3, repeats=1, warmup=1, seq_lens=(3,), top_ks=(4,),
                    indexes=("hnsw",), threads=1)


def test_tiny_sweep_end_to_end(tmp_path, monkeypatch):
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    path = main(TINY, tmp_path / "out")
    res = json.loads(path.read_text())
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
    assert (tmp_path / "out" / "timing.png").stat().st_size > 1000
    md = (tmp_path / "out" / "results.md").read_text()
    assert "| | S_1 | S_5 | SeqMatch: All | SeqMatch: Top 20 |" in md and "| ours, paper's way |" in md
    assert not list(scratch.iterdir())  # the temporary maps are gone


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
