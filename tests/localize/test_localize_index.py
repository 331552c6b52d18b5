"""The online localiser over an index map equals the one over the dataset the map was built from."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.localize.stream import index_reference
from seqnet.maps import MapConfig, build, load_map
from seqnet.search.ann import AnnConfig

CONF = LocalizeConfig(k=7, top_k=5, device="cpu")


def index_localizer(mp, method, conf=CONF, exact=False):
    conf = conf.replace(method=method)
    return conf.localizer(*index_reference(mp, conf), exact=exact)


def assert_same_track(a, b):
    assert [e.ref_index for e in a] == [e.ref_index for e in b]
    assert [e.ref_frame for e in a] == [e.ref_frame for e in b]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x.scores, y.scores, rtol=1e-4, atol=1e-4)
        assert x.confidence == pytest.approx(y.confidence, abs=1e-4)


@pytest.mark.parametrize(("conf", "method", "with_models"), [
    (MapConfig(seq_len=4, window="causal"), "hvpr", True),
    (MapConfig(seq_len=4, window="causal"), "seqnet", True),
    (MapConfig(seq_len=4, window="causal"), "s1+seqmatch", True),
    (MapConfig(shortlist="delta", rerank="raw+graph", seq_len=4, match_len=5, window="causal"),
     "hvpr-delta:raw+graph", False),
    (MapConfig(shortlist="delta", rerank="raw+vseqmatch", seq_len=4, window="causal"), "raw+vseqmatch", False),
    # a single-frame method searches every reference frame, the first L-1 of each sequence too (hunt 5 F1): from the
    # stored frames, or from the map's edge_shortlist.npy when the frames are another descriptor
    (MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=4, window="causal"), "single", False),
    (MapConfig(shortlist="single", seq_len=4, window="causal"), "single", True),
    (MapConfig(shortlist="s1", rerank="raw+seqmatch", seq_len=4, window="causal"), "s1", True),
])
def test_flat_index_map_equals_the_dataset_localizer(synth_dataset, synth_dir, map_models, tmp_path, conf, method,
                                                     with_models):
    used = map_models if with_models else ()
    mp = load_map(build(conf, synth_dir, tmp_path / "map", used), "cpu")
    test = synth_dataset.split("test")
    loc_map = index_localizer(mp, method)
    loc_ds = dataset_localizer(test, mp.models, CONF.replace(method=method, seq_len=conf.seq_len,
                                                              match_len=conf.match_len))
    assert loc_map.ref_items.tolist() == loc_ds.ref_items.tolist()
    a, b = list(replay(loc_map, test.query)), list(replay(loc_ds, test.query))
    assert any(e.ref_index >= 0 for e in a)
    assert_same_track(a, b)


def test_an_approximate_index_shortlists_through_the_index(synth_dataset, synth_dir, tmp_path):
    conf = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4, window="causal",
                     ann=AnnConfig(kind="hnsw", ef_search=256))
    mp = load_map(build(conf, synth_dir, tmp_path / "map"), "cpu")
    test = synth_dataset.split("test")
    approx = index_localizer(mp, mp.config.method.name)
    exact = index_localizer(mp, mp.config.method.name, exact=True)
    assert not approx.exact and exact.exact
    calls = []
    search = mp.search
    mp.search = lambda d, q, k, exact=False: (None if exact else calls.append(k)) or search(d, q, k, exact)
    a, b = list(replay(approx, test.query)), list(replay(exact, test.query))
    assert calls and all(k == 7 for k in calls)  # max(k, top_k) items through the index, per answered frame
    agree = np.mean([x.ref_index == y.ref_index for x, y in zip(a, b, strict=True)])
    assert agree >= 0.95  # HNSW with ef_search 256 over ~140 items is (nearly) exact


def test_index_maps_are_refused_when_they_do_not_fit(synth_dir, map_models, tmp_path):
    centred = load_map(build(MapConfig(seq_len=4), synth_dir, tmp_path / "c", map_models), "cpu")
    with pytest.raises(ConfigError, match="--window causal"):
        index_localizer(centred, "hvpr")
    causal = load_map(build(MapConfig(seq_len=4, window="causal"), synth_dir, tmp_path / "k", map_models), "cpu")
    with pytest.raises(ConfigError, match="cannot run method 'single'; valid for this map: hvpr, seqnet"):
        index_localizer(causal, "single")
    with pytest.raises(ConfigError, match="seq_len=5 but map"):
        index_localizer(causal, "hvpr", CONF.replace(seq_len=5))
    causal.meta["source"].pop("radius")
    with pytest.raises(ConfigError, match="no localisation radius"):
        index_reference(causal, CONF.replace(method="hvpr"))
    assert index_reference(causal, CONF.replace(method="hvpr", radius=3.0))[1] == 3.0


def one_line_error(capsys, argv, needle):
    assert cli(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1, err


def test_cli_streams_descriptors_against_an_index_map(synth_dir, map_models, tmp_path, capsys):
    mp = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--model", str(map_models[0]), "--model",
                str(map_models[1]), "--window", "causal", "--index", "hnsw", "--out", str(mp)]) == 0
    query = synth_dir / "query" / "descriptors.npy"
    out = tmp_path / "track.csv"
    assert cli(["-q", "localize", "--map", str(mp), "--query", str(query), "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == len(np.load(query)) and any(int(r["estimate"]) >= 0 for r in rows)
    capsys.readouterr()
    one_line_error(capsys, ["localize", "--map", str(mp), "--query", str(query), "--out", str(tmp_path / "b.csv"),
                            "--model", str(map_models[0])], "stores the models")
    one_line_error(capsys, ["localize", "--map", str(mp), "--query", str(query), "--out", str(tmp_path / "b.csv"),
                            "--split", "val"], "drop --split")
    one_line_error(capsys, ["localize", "--map", str(mp), "--query", str(query), "--out", str(tmp_path / "b.csv"),
                            "--method", "raw+seqmatch"], "cannot run method 'raw+seqmatch'")
