"""The parity matrix: one pipeline, four paths.

For every method name the tables generate with an online form (every shortlister × frames ×
matcher, ``hvpr-fused`` included), ``seqnet eval --window causal``, ``seqnet localize --dataset``,
``seqnet eval --index`` on a flat map and ``seqnet localize --map`` on that map give the same
ranking of every query item. A method without an online form is refused, never run as another.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.localize.stream import index_reference
from seqnet.maps import MapConfig, build, evaluate_map, load_map, load_query
from seqnet.matching.registry import SEQUENCE_MATCHERS
from seqnet.methods.grammar import FRAME_FEATURES, HVPR_FUSED
from seqnet.sequence.checkpoints import save_checkpoint
from seqnet.sequence.descriptors import SEQUENCE_DESCRIPTORS
from seqnet.sequence.model import SeqNet

ONLINE = [m for m, spec in SEQUENCE_MATCHERS.items() if spec.online]
RERANKERS = [f"{f}+{m}" for f in FRAME_FEATURES for m in ONLINE]
K, TOP_K = 6, 4


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A small synthetic route (three sequences), random S_L (L=3, w=2) and S_1, saved as files."""
    tmp = tmp_path_factory.mktemp("parity")
    ds = make_synthetic(places=100, dim=8, seed=7)
    torch.manual_seed(0)
    paths, models = [], {}
    for role, (seq_len, w) in {"seqnet": (3, 2), "s1": (1, 1)}.items():
        models[role] = SeqNet(8, 6, seq_len, w).eval()
        models[role].provenance = ds.reference.provenance
        paths.append(save_checkpoint(tmp / f"{role}.pt", models[role]))
    root = save_dataset(ds, tmp / "ds")
    return ds.split("test"), models, root, paths, tmp


def _causal_eval(ds, models, methods):
    # the localiser queries and indexes what eval scores for each method (every frame for single-frame methods)
    conf = EvalConfig(methods=tuple(methods), window="causal", ks=(K,), top_k=TOP_K, device="cpu")
    return evaluate(ds, conf, models)


def _track(loc, query):
    """The rankings of the frames with full causal windows, stacked."""
    est = [e for e in replay(loc, query) if e.full_window]
    return np.array([e.frame for e in est]), np.stack([e.ranked for e in est])


def test_every_knn_and_matching_method_online_equals_offline(world):
    ds, models, *_ = world
    methods = [*SEQUENCE_DESCRIPTORS, *(r for r in RERANKERS)]
    ev = _causal_eval(ds, models, methods)
    for name in methods:
        frames, ranked = _track(dataset_localizer(ds, models, LocalizeConfig(method=name, k=K, device="cpu")),
                                ds.query)
        assert frames.tolist() == ev.view(name).q_items.tolist(), name
        np.testing.assert_array_equal(ranked, ev.retrieved[name], err_msg=name)


@pytest.mark.parametrize("shortlist", list(SEQUENCE_DESCRIPTORS))
def test_every_hvpr_on_all_four_paths(world, shortlist):
    """eval --window causal = localize --dataset = eval --index (flat map) = localize --map, for every re-ranker."""
    ds, models, root, paths, tmp = world
    for rerank in RERANKERS:
        names = [f"hvpr-{shortlist}:{rerank}"] + ([f"{HVPR_FUSED}:{rerank}"] if shortlist == "seqnet" else [])
        ev = _causal_eval(ds, models, names)
        out = tmp / f"map-{shortlist}-{rerank}"
        mp = load_map(build(MapConfig(shortlist=shortlist, rerank=rerank, seq_len=3, window="causal", device="cpu"),
                            root, out, paths), "cpu")
        on_map = evaluate_map(mp, load_query(root, "test"), EvalConfig(methods=tuple(names), window="causal",
                                                                        ks=(K,), top_k=TOP_K))
        for name in names:
            conf = LocalizeConfig(method=name, k=K, top_k=TOP_K, device="cpu")
            _, online = _track(dataset_localizer(ds, models, conf), ds.query)
            _, online_map = _track(conf.localizer(*index_reference(mp, conf)), ds.query)
            for what, got in (("localize --dataset", online), ("eval --index", on_map.retrieved[name]),
                              ("localize --map", online_map)):
                np.testing.assert_array_equal(got, ev.retrieved[name], err_msg=f"{name}: {what}")


def test_fused_is_not_plain_hvpr_online(world):
    """hvpr-fused means the fused score on every path (it once ran as plain hvpr in the localiser)."""
    ds, models, *_ = world
    ev = _causal_eval(ds, models, ["hvpr", HVPR_FUSED])
    assert not np.array_equal(ev.scores["hvpr"], ev.scores[HVPR_FUSED])
    loc = dataset_localizer(ds, models, LocalizeConfig(method=HVPR_FUSED, k=K, top_k=TOP_K, device="cpu"))
    est = [e for e in replay(loc, ds.query) if e.full_window]
    np.testing.assert_allclose(np.stack([e.scores for e in est]), ev.scores[HVPR_FUSED], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", [m for m, spec in SEQUENCE_MATCHERS.items() if not spec.online])
def test_a_matcher_without_online_form_is_refused(world, name):
    ds, models, *_ = world
    with pytest.raises(ConfigError, match="no online form"):
        LocalizeConfig(method=f"raw+{name}")
    with pytest.raises(ConfigError, match="no online form"):
        LocalizeConfig(method=f"hvpr-single:raw+{name}")
