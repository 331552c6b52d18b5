"""Evaluation on a precomputed distance / similarity matrix equals evaluation on the descriptors it came from."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.eval.matrix import evaluate_matrix
from seqnet.reference.matrix import matrix_methods

METHODS = ("single", "raw+seqmatch", "raw+seqmatch-rev", "raw+vseqmatch", "raw+vseqmatch-rev", "raw+graph",
           "hvpr-single:raw+seqmatch", "hvpr-single:raw+seqmatch-rev")


def unit(x):
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def distances(ds):
    q, r = (torch.as_tensor(unit(t.descriptors), dtype=torch.float64) for t in (ds.query, ds.reference))
    return torch.cdist(q, r).numpy()


@pytest.mark.parametrize("window", ["centred", "causal"])
def test_a_distance_matrix_ranks_as_the_descriptors_do(synth_dataset, window):
    ds = synth_dataset.split("test")
    conf = EvalConfig(methods=METHODS, seq_len=4, ks=(1, 5, 20), window=window, top_k=10)
    a, b = evaluate_matrix(ds, distances(ds), conf), evaluate(ds, conf)
    for m in METHODS:
        np.testing.assert_array_equal(a.retrieved[m][:, :10], b.retrieved[m][:, :10], err_msg=m)
        np.testing.assert_allclose(a.scores[m][:, :10], b.scores[m][:, :10], rtol=1e-5, err_msg=m)
        assert a.results["methods"][m]["recall@1"] == b.results["methods"][m]["recall@1"]


def test_whole_map_seqmatch_on_a_matrix_is_blocked(synth_dataset, monkeypatch):
    """Whole-map SeqMatch reads blocks of matrix rows (memory bounded), never the [M, R, L] gather of every
    window pair that the re-ranking of a shortlist uses; the rankings are those of the descriptors."""
    import seqnet.matching.pairs as pairs

    def refuse(*a, **k):
        raise AssertionError("whole-map SeqMatch gathered every window pair")

    monkeypatch.setattr(pairs, "scores_from_distances", refuse)
    ds = synth_dataset.split("test")
    conf = EvalConfig(methods=("raw+seqmatch", "raw+seqmatch-rev"), seq_len=4, ks=(1, 5))
    a, b = evaluate_matrix(ds, distances(ds), conf), evaluate(ds, conf)
    for m in conf.methods:
        np.testing.assert_array_equal(a.retrieved[m], b.retrieved[m], err_msg=m)


def test_methods_that_need_descriptors_are_refused(synth_dataset):
    ds = synth_dataset.split("test")
    for name in ("smoothing", "raw+grh", "hvpr-delta:raw+seqmatch", "hvpr-single:raw+graph", "s1+seqmatch"):
        with pytest.raises(ConfigError, match="needs descriptors; on a distance matrix: single, raw"):
            evaluate_matrix(ds, distances(ds), EvalConfig(methods=(name,), seq_len=4))
    assert "hvpr-single:raw+seqmatch" in matrix_methods()


def test_cli_distances_and_similarities(synth_dataset, synth_dir, tmp_path, capsys):
    d = distances(synth_dataset)
    np.save(tmp_path / "d.npy", d)
    np.save(tmp_path / "s.npy", 1 - d**2 / 2)  # cosine similarity of unit vectors
    outs = {}
    for name, extra in (("d", []), ("s", ["--similarity"])):
        assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--distances", str(tmp_path / f"{name}.npy"),
                    *extra, "--out", str(tmp_path / name)]) == 0
        outs[name] = json.loads((tmp_path / name / "results.json").read_text())
    assert list(outs["d"]["methods"]) == ["single", "raw+seqmatch", "hvpr-single:raw+seqmatch"]
    assert outs["d"]["methods"]["single"]["recall@1"] == outs["s"]["methods"]["single"]["recall@1"]
    assert outs["s"]["inputs"]["similarity"] is True
    np.save(tmp_path / "bad.npy", d[:, :-1])
    assert cli(["eval", "--dataset", str(synth_dir), "--distances", str(tmp_path / "bad.npy")]) == 2
    assert "one row per query frame, one column per reference frame" in capsys.readouterr().err
    d[3, 4] = np.nan
    np.save(tmp_path / "nan.npy", d)
    assert cli(["eval", "--dataset", str(synth_dir), "--distances", str(tmp_path / "nan.npy")]) == 2
    assert "entry [3, 4] is nan" in capsys.readouterr().err
    assert cli(["eval", "--dataset", str(synth_dir), "--similarity"]) == 2


def test_a_range_split_evaluates_its_sub_matrix(synth_dataset, synth_dir, tmp_path, capsys):
    np.save(tmp_path / "d.npy", distances(synth_dataset))
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--distances", str(tmp_path / "d.npy"),
                "--split", "20:80", "--method", "single", "--out", str(tmp_path / "r")]) == 0
    sub = synth_dataset.split("20:80")
    want = evaluate_matrix(sub, distances(sub), EvalConfig(methods=("single",), seq_len=4))
    got = json.loads((tmp_path / "r" / "results.json").read_text())["methods"]["single"]
    assert got["queries"] == want.results["methods"]["single"]["queries"]
    assert got["recall@1"] == want.results["methods"]["single"]["recall@1"]
    assert cli(["eval", "--dataset", str(synth_dir), "--distances", str(tmp_path / "d.npy"), "--split", "nosuch"]) == 2
    assert "has no split 'nosuch'" in capsys.readouterr().err


ONLINE = ("single", "raw+seqmatch", "raw+vseqmatch", "raw+graph", "hvpr-single:raw+seqmatch")


@pytest.mark.parametrize("method", ONLINE)
def test_localize_streams_a_matrix_as_causal_eval_ranks_it(synth_dataset, synth_dir, tmp_path, method):
    """``seqnet localize --distances`` (rows streamed one per frame) answers as ``seqnet eval --distances
    --window causal`` on the same matrix, and as ``seqnet localize`` on the descriptors it came from."""
    import csv

    np.save(tmp_path / "d.npy", distances(synth_dataset))
    common = ["--dataset", str(synth_dir), "--seq-len", "4", "--method", method,
              *(["--top-k", "10"] if method.startswith("hvpr") else [])]  # refused for a method without a shortlist
    assert cli(["localize", *common, "--distances", str(tmp_path / "d.npy"), "--out", str(tmp_path / "m.csv")]) == 0
    assert cli(["localize", *common, "--out", str(tmp_path / "t.csv")]) == 0
    ev = evaluate_matrix(synth_dataset.split("test"), distances(synth_dataset.split("test")),
                         EvalConfig(methods=(method,), seq_len=4, window="causal", top_k=10))
    rows = {n: list(csv.DictReader(open(tmp_path / f"{n}.csv"))) for n in ("m", "t")}
    full = [r for r in rows["m"] if r["full_window"] == "1"]
    assert [int(r["estimate"]) for r in full] == ev.view(method).r_items[ev.retrieved[method][:, 0]].tolist()
    assert [r["estimate"] for r in rows["m"]] == [r["estimate"] for r in rows["t"]]
    summary = json.loads((tmp_path / "m.json").read_text())
    assert summary["inputs"]["similarity"] is False and summary["inputs"]["distances_digest"]


def test_localize_on_a_matrix_refuses_models_and_descriptor_methods(synth_dir, synth_dataset, tmp_path, capsys):
    np.save(tmp_path / "d.npy", distances(synth_dataset))
    base = ["localize", "--dataset", str(synth_dir), "--distances", str(tmp_path / "d.npy"), "--out",
            str(tmp_path / "m.csv")]
    assert cli([*base, "--method", "smoothing"]) == 2
    assert "needs descriptors; on a distance matrix" in capsys.readouterr().err
    assert cli([*base, "--model", str(tmp_path / "x.pt")]) == 2
    assert "no model applies" in capsys.readouterr().err
    assert cli(["localize", "--dataset", str(synth_dir), "--similarity", "--out", str(tmp_path / "m.csv")]) == 2


def test_the_finite_check_streams_blocks_of_rows_and_names_the_entry(tmp_path):
    from seqnet.core.errors import DatasetError
    from seqnet.eval.matrix import check_finite_rows

    m = np.zeros((50, 7))
    m[37, 5] = np.inf
    np.save(tmp_path / "m.npy", m)
    mm = np.load(tmp_path / "m.npy", mmap_mode="r")
    for block in (8, 7 * 8 * 3, 1 << 20):  # one row per block, 3 rows, all of it
        with pytest.raises(DatasetError, match=r"entry \[37, 5\] is inf"):
            check_finite_rows(mm, "m.npy", block_bytes=block)
    check_finite_rows(np.load(tmp_path / "m.npy")[:37], "m.npy", block_bytes=8)


def test_a_vpr_bench_precomputed_file_is_read_as_its_score_matrix(synth_dataset, synth_dir, tmp_path, capsys):
    """VPR-Bench's ``precomputed_data_corrected.npy`` (evaluate_vpr_techniques.py: an object array of query
    indices, best references, best scores, the [Nq, Nr] score matrix, encode and match times) is read by the
    data-only unpickler and evaluated as the matrix it holds; without --similarity it is refused."""
    s = 1 - distances(synth_dataset) ** 2 / 2
    pre = np.empty(6, dtype=object)
    pre[:] = [np.arange(len(s)), s.argmax(1), s.max(1), s, 0.01, 0.02]
    np.save(tmp_path / "pre.npy", pre, allow_pickle=True)
    np.save(tmp_path / "s.npy", s)
    got = {}
    for name in ("pre", "s"):
        assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--distances", str(tmp_path / f"{name}.npy"),
                    "--similarity", "--json", str(tmp_path / f"{name}.json")]) == 0
        got[name] = json.loads((tmp_path / f"{name}.json").read_text())["methods"]
    keep = ("recall@", "auc", "queries")
    figures = {m: {k: v for k, v in r.items() if k.startswith(keep)} for m, r in got["s"].items()}
    assert figures and all({k: got["pre"][m][k] for k in f} == f for m, f in figures.items())
    capsys.readouterr()
    assert cli(["eval", "--dataset", str(synth_dir), "--distances", str(tmp_path / "pre.npy")]) == 2
    assert "add --similarity" in (err := capsys.readouterr().err) and "--no-similarity" in err
    # a VPR-Bench file whose matrix holds distances: the sense check said "drop --similarity", which was refused, so
    # its right figures could not be reached; --no-similarity reads it as distances
    dist = np.empty(6, dtype=object)
    dist[:] = [np.arange(len(s)), s.argmax(1), s.max(1), 1 - s, 0.01, 0.02]
    np.save(tmp_path / "dist.npy", dist, allow_pickle=True)
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--distances", str(tmp_path / "dist.npy"),
                "--similarity"]) == 0
    assert "--no-similarity for a VPR-Bench file" in capsys.readouterr().err
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--distances", str(tmp_path / "dist.npy"),
                "--no-similarity", "--json", str(tmp_path / "dist.json")]) == 0
    read = json.loads((tmp_path / "dist.json").read_text())["methods"]
    assert {m: read[m]["recall@1"] for m in got["s"]} == {m: got["s"][m]["recall@1"] for m in got["s"]}
    other = np.empty(2, dtype=object)
    other[:] = [1, "x"]
    np.save(tmp_path / "other.npy", other, allow_pickle=True)
    assert cli(["eval", "--dataset", str(synth_dir), "--distances", str(tmp_path / "other.npy"), "--similarity"]) == 2
    assert "not a matrix of numbers" in capsys.readouterr().err


def test_a_transposed_matrix_is_read_as_such_by_eval_and_localize(synth_dataset, synth_dir, tmp_path, capsys):
    """--transposed: the file is [N_reference, N_query] (VPR_Tutorial's S); eval and localize answer as on the
    matrix the right way round, and a file of the wrong shape names the layout it expected."""
    d = distances(synth_dataset)
    np.save(tmp_path / "d.npy", d)
    np.save(tmp_path / "t.npy", np.ascontiguousarray(d.T))
    common = ["--dataset", str(synth_dir), "--seq-len", "4", "--method", "single"]
    got = {}
    for name, extra in (("d", []), ("t", ["--transposed"])):
        assert cli(["eval", *common, "--distances", str(tmp_path / f"{name}.npy"), *extra,
                    "--json", str(tmp_path / f"e{name}.json")]) == 0
        got[name] = json.loads((tmp_path / f"e{name}.json").read_text())
        assert cli(["localize", *common, "--distances", str(tmp_path / f"{name}.npy"), *extra,
                    "--out", str(tmp_path / f"{name}.csv")]) == 0
    assert got["d"]["methods"]["single"]["recall@1"] == got["t"]["methods"]["single"]["recall@1"]
    assert got["t"]["inputs"]["transposed"] is True
    import csv

    rows = {n: [{k: v for k, v in r.items() if "ms" not in k and "latency" not in k}
                for r in csv.DictReader(open(tmp_path / f"{n}.csv"))] for n in "dt"}
    assert rows["d"] == rows["t"] and len(rows["d"]) > 10
    capsys.readouterr()
    if d.shape[0] != d.shape[1]:
        assert cli(["eval", *common, "--distances", str(tmp_path / "d.npy"), "--transposed"]) == 2
        assert "one row per reference frame" in capsys.readouterr().err
        assert cli(["localize", *common, "--distances", str(tmp_path / "t.npy"), "--out", str(tmp_path / "x.csv")]) == 2
        assert "it is the other way round: pass --transposed" in capsys.readouterr().err
    assert cli(["eval", *common, "--transposed"]) == 2
    capsys.readouterr()
    assert cli(["localize", *common, "--distances", str(tmp_path / "d.npy"), "--similarity",  # the other sense
                "--out", str(tmp_path / "s.csv")]) == 0
    assert "reads much better as distances (the other sense reading)" in (err := capsys.readouterr().err)
    assert "drop --similarity" in err
