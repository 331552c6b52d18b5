"""HVPR's K chosen on val when a map is built, stored in map.json and used by localize --map and eval --index: the
same K as localize --dataset on the same data, unless --top-k is given."""

from __future__ import annotations

import json

import pytest

from seqnet.cli import main as cli

METHOD = "hvpr-delta:raw+graph"  # on the synthetic dataset its val choice is K 10, not the default 20


@pytest.fixture
def built(synth_dir, tmp_path):
    mp = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+graph",
                "--seq-len", "4", "--window", "causal", "--out", str(mp)]) == 0
    return mp


def _k(path):
    return json.loads(path.read_text())["config"]["top_k"]


def test_localize_dataset_map_and_eval_index_use_the_same_k(synth_dir, built, tmp_path, capsys):
    assert cli(["-q", "localize", "--dataset", str(synth_dir), "--method", METHOD, "--seq-len", "4",
                "--out", str(tmp_path / "t1.csv")]) == 0
    k_dataset = _k(tmp_path / "t1.json")
    assert k_dataset != 20  # chosen on val, not the default
    sel = json.loads((built / "map.json").read_text())["selection"]
    assert sel["split"] == "val" and sel["settings"] == {"top_k": k_dataset}
    assert sel["hvpr"][0]["recall"] > 0 and "chosen on the val split" in sel["hvpr"][0]["reason"]
    query = synth_dir / "query" / "descriptors.npy"
    capsys.readouterr()
    assert cli(["-q", "localize", "--map", str(built), "--query", str(query), "--out", str(tmp_path / "t2.csv")]) == 0
    assert _k(tmp_path / "t2.json") == k_dataset
    assert f"K {k_dataset}, the map's (chosen on the val split" in capsys.readouterr().out
    assert cli(["-q", "eval", "--index", str(built), "--dataset", str(synth_dir), "--window", "causal",
                "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["methods"][METHOD]["method"]["top_k"] == k_dataset
    assert f"K {k_dataset}, the map's (chosen on the val split" in out


def test_an_explicit_top_k_wins_and_is_said(synth_dir, built, tmp_path, capsys):
    query = synth_dir / "query" / "descriptors.npy"
    capsys.readouterr()
    assert cli(["-q", "localize", "--map", str(built), "--query", str(query), "--top-k", "20",
                "--out", str(tmp_path / "t.csv")]) == 0
    assert _k(tmp_path / "t.json") == 20
    assert "--top-k 20 as given (the map's K 10, chosen on val, not used)" in capsys.readouterr().out
    capsys.readouterr()
    assert cli(["-q", "eval", "--index", str(built), "--dataset", str(synth_dir), "--window", "causal", "--top-k",
                "20", "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["methods"][METHOD]["method"]["top_k"] == 20
    assert "--top-k 20 as given" in capsys.readouterr().out


def test_a_map_without_the_record_keeps_the_default(synth_dir, built, tmp_path):
    meta = json.loads((built / "map.json").read_text())
    del meta["selection"]  # as written before maps carried it
    (built / "map.json").write_text(json.dumps(meta))
    query = synth_dir / "query" / "descriptors.npy"
    assert cli(["-q", "localize", "--map", str(built), "--query", str(query), "--out", str(tmp_path / "t.csv")]) == 0
    assert _k(tmp_path / "t.json") == 20


def test_a_whole_route_map_says_why_and_takes_its_k_at_build(synth_dir, tmp_path, capsys):
    """hunt 5 F7: a map of --split all gets no K chosen on val; the line spoke of an 'evaluated split' (index build
    evaluates nothing) and hinted --top-k, which index build refused. It takes --top-k now, stored and said."""
    flags = ["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+graph",
             "--seq-len", "4", "--window", "causal", "--split", "all"]
    assert cli([*flags, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "the map's split 'all' holds the val queries" in err and "evaluated split" not in err, err
    assert "seqnet index build --top-k" in err
    assert cli([*flags, "--top-k", "10", "--out", str(tmp_path / "b")]) == 0
    assert "K 10 as given (--top-k); stored in the map" in capsys.readouterr().err
    sel = json.loads((tmp_path / "b" / "map.json").read_text())["selection"]
    assert sel["settings"] == {"top_k": 10} and sel["given"] == {"top_k": 10}
    query = synth_dir / "query" / "descriptors.npy"
    assert cli(["localize", "--map", str(tmp_path / "b"), "--query", str(query), "--out", str(tmp_path / "t.csv")]) == 0
    assert _k(tmp_path / "t.json") == 10
    assert "K 10, the map's (given to seqnet index build)" in "".join(capsys.readouterr())
    assert cli(["-q", "eval", "--index", str(tmp_path / "b"), "--dataset", str(synth_dir), "--window", "causal",
                "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["methods"][METHOD]["method"]["top_k"] == 10


def test_a_setting_the_maps_method_does_not_take_is_refused(synth_dir, tmp_path):
    from seqnet.core.errors import ConfigError
    from seqnet.maps import MapConfig, build

    with pytest.raises(ConfigError, match="--fuse-weight is not a setting of the map's method .* it takes --top-k"):
        build(MapConfig(shortlist="delta", rerank="raw+graph", seq_len=4), synth_dir, tmp_path / "m",
              settings={"fuse_weight": 0.5})
    assert not (tmp_path / "m").exists()


def test_the_python_route_uses_the_maps_k_as_the_cli_does(synth_dir, built, tmp_path):
    """hunt 5 F4: docs/scale.md's Python equivalent of localize --map used K 20 whatever the map stored."""
    import csv

    import numpy as np

    from seqnet.localize.config import LocalizeConfig
    from seqnet.localize.stream import index_reference
    from seqnet.maps import load_map

    query = synth_dir / "query" / "descriptors.npy"
    assert cli(["-q", "localize", "--map", str(built), "--query", str(query), "--out", str(tmp_path / "t.csv")]) == 0
    by_cli = [(int(r["estimate"]), r["confidence"]) for r in csv.DictReader((tmp_path / "t.csv").open())]
    conf = LocalizeConfig(method=METHOD)  # K not given: the map's
    loc = conf.localizer(*index_reference(load_map(built), conf))
    assert loc.top_k == 10 == conf.for_reference(loc.ref).top_k
    est = [loc.step(x) for x in np.load(query)]
    assert [e.ref_frame for e in est] == [e for e, _ in by_cli]
    assert [f"{e.confidence:.6f}" for e in est] == [c for _, c in by_cli]
    assert LocalizeConfig(method=METHOD, top_k=20).localizer(*index_reference(load_map(built), conf)).top_k == 20


def test_a_given_top_k_is_not_called_the_defaults(synth_dir, tmp_path, capsys):
    """hunt 5 F6: --top-k given (and used) against a map without a stored K, or a dataset split holding the val
    queries, was said to be 'the defaults' / '(the defaults kept)'."""
    mp = tmp_path / "a"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+graph",
                "--seq-len", "4", "--window", "causal", "--split", "all", "--out", str(mp)]) == 0
    query = synth_dir / "query" / "descriptors.npy"
    capsys.readouterr()
    assert cli(["localize", "--map", str(mp), "--query", str(query), "--top-k", "10", "--out",
                str(tmp_path / "t.csv")]) == 0
    said = "".join(capsys.readouterr())
    assert f"{METHOD}: --top-k 10 as given (the map stores none:" in said and ": the defaults (" not in said, said
    assert _k(tmp_path / "t.json") == 10
    assert cli(["localize", "--dataset", str(synth_dir), "--split", "all", "--method", METHOD, "--seq-len", "4",
                "--top-k", "10", "--out", str(tmp_path / "d.csv")]) == 0
    said = "".join(capsys.readouterr())
    assert "defaults kept" not in said, said
    record = json.loads((tmp_path / "d.json").read_text())
    assert record["config"]["top_k"] == 10 and "selection" not in record
