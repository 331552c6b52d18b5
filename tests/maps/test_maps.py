"""Maps: build → load → eval --index equals the exact evaluation (flat index); refusals; ownership; CLI errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError, OutputError
from seqnet.core.provenance import ProvenanceError
from seqnet.core.provenance import make as make_provenance
from seqnet.data.io import load_dataset, save_dataset
from seqnet.eval.evaluate import EvalConfig
from seqnet.eval.evaluate import main as eval_main
from seqnet.maps import MapConfig, MapError, build, evaluate_main, load_map
from seqnet.matching.hvpr import hvpr, pair_scores
from seqnet.matching.on_disk import pair_scores_on_map

FREE = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4)  # a model-free map


def results(path):
    return json.loads(path.read_text())["methods"]


@pytest.mark.parametrize("with_models", [False, True])
def test_flat_map_equals_the_exact_evaluation(synth_dir, map_models, tmp_path, with_models):
    conf = MapConfig() if with_models else FREE
    used = map_models if with_models else ()
    mp_path = build(conf, synth_dir, tmp_path / "map", used)
    mp = load_map(mp_path)
    methods = [mp.config.method.name, mp.config.method.shortlist, mp.config.method.rerank]
    econf = EvalConfig(methods=methods, seq_len=4, ks=(1, 5, 10))
    exact = results(eval_main(econf, synth_dir, tmp_path / "exact", used))
    mapped = results(evaluate_main(econf, synth_dir, mp_path, tmp_path / "mapped"))
    for name in methods:
        for key in ("recall@1", "recall@5", "recall@10", "queries", "no_positive"):
            assert mapped[name][key] == pytest.approx(exact[name][key]), (name, key)
    assert mapped[methods[0]]["shortlist_recall@20"] == 1.0
    assert mp.nbytes > 0 and set(mp.models) == ({"seqnet", "s1"} if with_models else set())
    said = [json.loads((tmp_path / d / "results.json").read_text())["descriptors"] for d in ("exact", "mapped")]
    assert said[0] == said[1] and said[1]["reference"]["provenance"]  # the map's descriptors, as the dataset's


@pytest.mark.parametrize("window", ["centred", "causal"])
def test_anchored_matchers_on_a_map_follow_its_window_mode(synth_dir, tmp_path, window):
    """A graph-re-ranked map pins the item's own frame, as the evaluation: centre or newest frame."""
    conf = MapConfig(shortlist="delta", rerank="raw+graph", seq_len=4, window=window)
    mp_path = build(conf, synth_dir, tmp_path / "map")
    mp = load_map(mp_path)
    methods = [mp.config.method.name, "raw+graph"]
    econf = EvalConfig(methods=methods, seq_len=4, ks=(1, 5), window=window)
    exact = results(eval_main(econf, synth_dir, tmp_path / "exact"))
    mapped = results(evaluate_main(econf, synth_dir, mp_path, tmp_path / "mapped"))
    for name in methods:
        assert mapped[name]["recall@1"] == pytest.approx(exact[name]["recall@1"]), name
        assert mapped[name]["recall@5"] == pytest.approx(exact[name]["recall@5"]), name


def test_map_api_matches_hvpr(synth_dataset, synth_dir, tmp_path):
    mp = load_map(build(FREE, synth_dir, tmp_path / "map"))
    qd = mp.describe(synth_dataset.split("test").query)
    q_short, q_frames = qd.items(mp.config.shortlist), qd.frames(mp.config.frames_descriptor)
    got = mp.localize(q_short, q_frames, qd.side.match_starts, top_k=10, k=30)
    want = hvpr(q_short, np.asarray(mp.shortlist), q_frames, np.asarray(mp.frames), 4, qd.side.match_starts,
                mp.match_starts, top_k=10, k=30)
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_allclose(got[0], want[0], rtol=1e-5)
    assert mp.positions[mp.items].shape == (len(mp.items), 2) and len(mp.names) == len(mp.frames)


def test_compact_rerank_equals_the_whole_map(rng):
    frames = rng.standard_normal((300, 8)).astype(np.float32)
    query = rng.standard_normal((40, 8)).astype(np.float32)
    r_starts = np.arange(296)
    q_starts = rng.integers(0, 36, 12)
    cand = rng.integers(-1, 296, (12, 7))
    cand[0] = -1  # a query without any candidate
    want = pair_scores(query, frames, 5, q_starts, r_starts, cand).numpy()
    got = pair_scores_on_map(query, frames, 5, q_starts, r_starts, cand, block_bytes=7 * 5 * 8 * 4 * 3).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5)  # 3 queries per block, in candidate order
    assert np.isinf(got[0]).all() and np.isinf(got[cand == -1]).all()


def test_hnsw_float16_map_reports_its_shortlist_recall(synth_dir, tmp_path):
    conf = FREE.replace(ann={"kind": "hnsw"}, dtype="float16", split="all")
    mp = load_map(build(conf, synth_dir, tmp_path / "map"))
    assert mp.frames.dtype == np.float16 and mp.index is not None
    res = results(evaluate_main(EvalConfig(split="all"), synth_dir, mp.path, tmp_path / "out"))
    assert set(res) == {"hvpr-delta:raw+seqmatch", "delta"}
    assert 0.8 <= res["delta"]["shortlist_recall@20"] <= 1.0


def test_queries_of_another_provenance_or_dimension_are_refused(synth_dataset, synth_dir, tmp_path):
    mp_path = build(FREE, synth_dir, tmp_path / "map")
    other = load_dataset(synth_dir, mmap=False)
    other.query.provenance = make_provenance("synthetic", {"seed": 99}, dim=16)
    save_dataset(other, tmp_path / "other")
    with pytest.raises(ProvenanceError, match="made differently"):
        evaluate_main(EvalConfig(), tmp_path / "other", mp_path, tmp_path / "o1")
    wide = load_dataset(synth_dir, mmap=False)
    for t in (wide.reference, wide.query):
        t.descriptors = np.concatenate([t.descriptors, t.descriptors], axis=1)
        t.provenance = None
    save_dataset(wide, tmp_path / "wide")
    with pytest.raises(MapError, match="D=32"):
        evaluate_main(EvalConfig(), tmp_path / "wide", mp_path, tmp_path / "o2")


def test_a_directory_with_a_users_file_is_not_replaced(synth_dir, tmp_path):
    out = tmp_path / "map"
    build(FREE, synth_dir, out)
    build(FREE.replace(seq_len=3), synth_dir, out)  # seqnet's own map: replaced
    assert load_map(out).config.seq_len == 3
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="notes.txt"):
        build(FREE, synth_dir, out)
    assert (out / "notes.txt").read_text() == "mine" and load_map(out).config.seq_len == 3


def test_a_damaged_map_is_refused(synth_dir, tmp_path):
    out = build(FREE, synth_dir, tmp_path / "map")
    (out / "frames.npy").unlink()
    with pytest.raises(MapError, match="frames.npy"):
        load_map(out)
    with pytest.raises(MapError, match="not a seqnet map"):
        load_map(synth_dir)


def one_line_error(capsys, argv, pattern):
    capsys.readouterr()
    assert cli(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and pattern in err[0] and "Traceback" not in err[0], err


def test_cli_build_and_eval(synth_dir, map_models, tmp_path, capsys):
    out = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--model", str(map_models[0]), "--model",
                str(map_models[1]), "--index", "ivf-flat", "--nlist", "2", "--out", str(out)]) == 0
    assert "ivf-flat" in capsys.readouterr().out
    res_json = tmp_path / "r.json"
    assert cli(["-q", "eval", "--dataset", str(synth_dir), "--index", str(out), "--json", str(res_json)]) == 0
    text = capsys.readouterr().out
    assert "hvpr" in text and "shortlist_recall@20" in text
    assert json.loads(res_json.read_text())["config"]["index"] == str(out)
    one_line_error(capsys, ["index", "build", "--dataset", str(synth_dir), "--out", str(tmp_path / "m2")],
                   "--shortlist single (or delta) --rerank raw+seqmatch")
    one_line_error(capsys, ["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                            "raw+seqmatch", "--index", "ivf-pq", "--pq-m", "5", "--out", str(tmp_path / "m3")],
                   "pq_m dividing D=16")
    assert not (tmp_path / "m3").exists()
    one_line_error(capsys, ["eval", "--dataset", str(synth_dir), "--index", str(tmp_path / "nope")],
                   "map directory not found")
    one_line_error(capsys, ["eval", "--dataset", str(synth_dir), "--index", str(out), "--model", str(map_models[0])],
                   "--index uses the map's models")
    one_line_error(capsys, ["eval", "--dataset", str(synth_dir), "--index", str(out), "--method", "single"],
                   "cannot run method 'single'")
    one_line_error(capsys, ["eval", "--dataset", str(synth_dir), "--index", str(out), "--seq-len", "3"],
                   "seq_len=3 but map")
    one_line_error(capsys, ["localize", "--map", str(out), "--query", str(synth_dir / "query" / "descriptors.npy"),
                            "--out", str(tmp_path / "t.csv")], "--window causal")


def test_a_report_with_index_holds_the_results_and_says_what_a_map_lacks(synth_dir, map_models, tmp_path, capsys):
    """``eval --index MAP --report`` writes report.html beside results.json: the summary, the results table (every
    method and its R@1 as in results.json), the extra radii; the distance matrix and the gallery, which read the
    reference side as a dataset, are a line saying why."""
    mp = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--model", str(map_models[0]), "--model",
                str(map_models[1]), "--out", str(mp)]) == 0
    rep = tmp_path / "rep"
    assert cli(["-q", "eval", "--dataset", str(synth_dir), "--index", str(mp), "--report", "--extra-radius", "9",
                "--out", str(rep)]) == 0
    assert f"report: {rep / 'report.html'}" in capsys.readouterr().out
    res = json.loads((rep / "results.json").read_text())
    page = (rep / "report.html").read_text()
    assert res["methods"] and "learned_below_baseline" in res
    for name, entry in res["methods"].items():
        assert f"<tr><td>{name}</td>" in page and f"<td>{entry['recall@1']:.3f}</td>" in page
    for section in ("summary", "results", "radii", "recall", "pr", "matrix", "gallery"):
        assert f'<section id="{section}">' in page, section
    assert "No distance matrix: the queries were evaluated against a prebuilt map (seqnet eval --index)" in page
    assert "No gallery: the queries were evaluated against a prebuilt map" in page
    assert f"<tr><td>reference</td><td>the map {mp}</td></tr>" in page
    radii = page.split('<section id="radii">')[1].split("</section>")[0]
    first = next(iter(res["methods"]))
    r1 = res["methods"][first]["radii"]["9.0"]["recall@1"]
    assert f"<tr><td>{first}</td><td>9</td><td>{r1:.3f}</td>" in radii


def test_explicit_positives_apply_to_a_map_of_the_same_dataset_only(synth_dir, tmp_path, capsys):
    from seqnet.data.positives import Positives

    ds = load_dataset(synth_dir, mmap=False)
    d = np.linalg.norm(ds.query.positions[:, None] - ds.reference.positions[None], axis=-1)
    ds.positives = Positives.from_lists([np.flatnonzero(row <= 3.0) for row in d])  # stricter than the radius
    save_dataset(ds, tmp_path / "pos")
    econf = EvalConfig(methods=["hvpr-delta:raw+seqmatch"], seq_len=4)
    exact = results(eval_main(econf, tmp_path / "pos", tmp_path / "exact"))
    mp_path = build(FREE, tmp_path / "pos", tmp_path / "map")
    mapped = results(evaluate_main(econf, tmp_path / "pos", mp_path, tmp_path / "mapped"))
    assert mapped["hvpr-delta:raw+seqmatch"]["recall@1"] == exact["hvpr-delta:raw+seqmatch"]["recall@1"]
    assert json.loads((tmp_path / "mapped" / "results.json").read_text())["config"]["ground_truth"] == \
        "explicit positives"
    assert cli(["eval", "--dataset", str(tmp_path / "pos"), "--index", str(mp_path), "--method",
                     "hvpr-delta:raw+seqmatch", "--seq-len", "4"]) == 0
    said = capsys.readouterr().out
    assert "explicit positives" in said and "radius" not in said.split("\n")[0], said  # not "radius 1" (exact-frame)
    foreign = build(FREE, synth_dir, tmp_path / "foreign")
    with pytest.raises(ConfigError, match="explicit positives"):
        evaluate_main(econf, tmp_path / "pos", foreign, tmp_path / "o")


def test_a_map_with_a_faiss_factory_string(synth_dir, tmp_path, capsys):
    from seqnet.cli import main as cli_main

    out = tmp_path / "map"
    assert cli_main(["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+seqmatch",
                     "--index", "IVF2,Flat", "--split", "all", "--out", str(out), "--device", "cpu"]) == 0
    mp = load_map(out)
    assert mp.index is not None and mp.config.ann.kind == "IVF2,Flat" and mp.index.nlist == 2
    res = results(evaluate_main(EvalConfig(split="all"), synth_dir, mp.path, tmp_path / "out"))
    assert res["delta"]["method"]["index"] == "IVF2,Flat" and res["delta"]["recall@1"] > 0
    capsys.readouterr()
    assert cli_main(["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                     "raw+seqmatch", "--index", "IVF2,Nope", "--out", str(tmp_path / "bad")]) == 2
    assert "FAISS cannot make index 'IVF2,Nope'" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()  # refused before any work


def test_an_edited_map_is_refused(synth_dir, map_models, tmp_path):
    """A map is written whole: an array, the index or a model changed afterwards is refused on open."""
    import shutil

    from seqnet.maps.map import MapError

    built = build(MapConfig(seq_len=4), synth_dir, tmp_path / "map", map_models)
    meta = json.loads((built / "map.json").read_text())
    assert {"items.npy", "shortlist.npy", "frames.npy", "models/seqnet.pt"} <= set(meta["checksums"])
    for name, edit in (("items.npy", lambda p: np.save(p, np.where(np.arange(len(np.load(p))) == 0, -1,
                                                                   np.load(p)))),
                       ("models/seqnet.pt", lambda p: shutil.copy(map_models[0], p)),
                       ("positions.npy", lambda p: np.save(p, np.full_like(np.load(p), np.nan)))):
        copy = tmp_path / f"edited-{name.replace('/', '-')}"
        shutil.copytree(built, copy)
        edit(copy / name)
        with pytest.raises(MapError, match="changed since the map was written"):
            load_map(copy)
    legacy = tmp_path / "legacy"  # a map without checksums (0.2) is still checked for what it holds
    shutil.copytree(built, legacy)
    meta.pop("checksums")
    (legacy / "map.json").write_text(json.dumps(meta))
    np.save(legacy / "positions.npy", np.full_like(np.load(legacy / "positions.npy"), np.nan))
    with pytest.raises(MapError, match="NaN"):
        load_map(legacy)
    np.save(legacy / "positions.npy", np.load(built / "positions.npy"))
    (legacy / "names.txt").write_text("a\nb\n")
    with pytest.raises(MapError, match="2 names for"):
        load_map(legacy)


def test_index_check_finds_a_change_the_sampled_hash_misses(synth_dir, tmp_path, capsys):
    """`seqnet index check` opens the map as eval does; --full hashes every byte, so a change between the
    sampled blocks of a large file is found too."""
    from seqnet.cli import main as cli_main

    built = build(FREE.replace(split="all"), synth_dir, tmp_path / "map")
    assert cli_main(["index", "check", str(built), "--full"]) == 0
    assert "files checked (every byte hashed)" in capsys.readouterr().out
    frames = np.load(built / "frames.npy", mmap_mode="r+")
    size = (built / "frames.npy").stat().st_size
    row = (size // 2 + 3000 - 128) // (frames.shape[1] * 4)  # inside no sampled block
    frames[row, 0] += 1.0
    frames.flush()
    del frames
    if size > 2 * 65536 + 16 * 4096:  # the sampled hash cannot see it
        assert cli_main(["index", "check", str(built)]) == 0
    capsys.readouterr()
    assert cli_main(["index", "check", str(built), "--full"]) == 2
    assert "frames.npy changed since the map was written" in capsys.readouterr().err


def test_a_causal_map_evaluated_with_the_default_window_names_the_flag(synth_dir, tmp_path, capsys):
    """``eval --index MAP`` of a causal map without --window: the refusal gives ``--window causal``."""
    mp_path = build(MapConfig(shortlist="delta", rerank="raw+graph", seq_len=4, window="causal"), synth_dir,
                    tmp_path / "map")
    one_line_error(capsys, ["eval", "--dataset", str(synth_dir), "--index", str(mp_path), "--seq-len", "4"],
                   "uses 'causal' windows (hint: --window causal, the map's")
    assert cli(["-q", "eval", "--dataset", str(synth_dir), "--index", str(mp_path), "--window", "causal"]) == 0


def test_eval_index_records_the_descriptors_as_seqnet_eval_does(tmp_path, synth_dataset):
    """Review L5: eval --index recorded `descriptors` without the dataset's describe/pca records, so a dataset
    whose traverses carry no provenance got method None there and the describer in seqnet eval's results.json."""
    import dataclasses

    from seqnet.data.io import save_dataset
    from seqnet.eval.evaluate import EvalConfig
    from seqnet.eval.evaluate import main as eval_main
    from seqnet.maps import MapConfig, build
    from seqnet.maps.evaluate import main as map_eval

    bare = dataclasses.replace(synth_dataset, reference=dataclasses.replace(synth_dataset.reference, provenance=None),
                               query=dataclasses.replace(synth_dataset.query, provenance=None),
                               extra={"describe": {"method": "netvlad", "views": ["raw", "equalize"]},
                                      "pca": {"dims": 16}})
    data = save_dataset(bare, tmp_path / "ds")
    index = build(MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=4), data, tmp_path / "map")
    conf = EvalConfig(methods=("single",), split="test", device="cpu")
    want = eval_main(conf, data, None, json=tmp_path / "a.json").data["descriptors"]
    got = map_eval(conf, data, index, None, json=tmp_path / "b.json").data["descriptors"]
    assert want["query"]["method"] == "netvlad" and want["query"]["pca"] == 16
    assert got == want
