"""The online Localizer equals the offline evaluation on causal windows, frame by frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.data.synth import make_synthetic
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.matching.velocity import velocity_topk
from seqnet.sequence.model import SeqNet


@pytest.fixture(scope="module")
def small():
    ds = make_synthetic(places=100, dim=12, seed=3)
    torch.manual_seed(0)
    models = {"seqnet": SeqNet(12, 8, seq_len=4, w=2).eval(), "s1": SeqNet(12, 8, seq_len=1, w=1).eval()}
    for m in models.values():
        m.provenance = ds.reference.provenance
    return ds, models


def loc_of(ds, models, method, **kw):
    """The localiser of ``method`` over the reference traverse of ``ds`` (CPU)."""
    return dataset_localizer(ds, models, LocalizeConfig(method=method, device="cpu", **kw))


METHODS = ["single", "s1", "seqnet", "delta", "raw+seqmatch", "s1+seqmatch", "raw+seqmatch-rev", "raw+vseqmatch",
           "s1+graph", "delta+seqmatch", "hvpr", "hvpr-single:raw+vseqmatch", "hvpr-delta:s1+graph"]
CASES = [(m, None) for m in METHODS] + [(m, 6) for m in ("seqnet", "s1+seqmatch", "raw+vseqmatch", "s1+graph", "hvpr")]


@pytest.mark.parametrize(("method", "match_len"), CASES)
def test_stream_equals_causal_evaluation(small, method, match_len):
    ds, models = small
    # the localiser queries and indexes what eval scores for each method: every frame for a single-frame method
    conf = EvalConfig(window="causal", match_len=match_len, ks=(1, 7), top_k=5, device="cpu")
    ev = evaluate(ds, conf.replace(methods=(method,), split="all"), models)  # every frame, as the replay
    view = ev.view(method)
    loc = loc_of(ds, models, method, match_len=match_len, k=7, top_k=5)
    assert loc.ref_items.tolist() == view.r_items.tolist()
    est = list(replay(loc, ds.query))
    assert [e.frame for e in est] == list(range(len(ds.query)))
    full = [e for e in est if e.full_window]
    assert [e.frame for e in full] == view.q_items.tolist()  # the comparable frames: full causal windows
    if method in ("single", "s1"):
        assert len(full) == len(ds.query) and len(view.r_items) == len(ds.reference)
    ranked = np.stack([e.ranked for e in full])
    scores = np.stack([e.scores for e in full])
    np.testing.assert_array_equal(ranked, ev.retrieved[method])
    np.testing.assert_allclose(scores, ev.scores[method], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose([e.confidence for e in full], ev.confidence[method], atol=1e-4)
    assert all(e.ref_frame == view.r_items[e.ref_index] and e.latency_ms > 0 for e in full)


def test_early_frames_and_resets(small):
    ds, models = small
    t = ds.query.subset(0, 30)
    bounds = np.array([[0, 12]] * 12 + [[12, 30]] * 18)
    t = Traverse(t.descriptors, t.positions, seq_bounds=bounds, provenance=t.provenance)
    loc = loc_of(ds, models, "single", seq_len=4, match_len=5)
    est = list(replay(loc, t))
    assert all(e.ref_index >= 0 and e.full_window for e in est)  # a single frame is a whole window: every frame
    loc = loc_of(ds, models, "raw+seqmatch", seq_len=4, match_len=5)
    est = list(replay(loc, t))
    assert [e.ref_index >= 0 for e in est[:6]] == [False] * 4 + [True] * 2
    assert [e.full_window for e in est[10:18]] == [True, True, False, False, False, False, True, True]
    assert est[12].ref_index == -1 and np.isnan(est[12].score) and est[12].confidence == 0.0


def test_anchor_end_equals_matcher_with_end_anchor(small):
    ds, _ = small
    q, r = ds.query.descriptors, ds.reference.descriptors
    loc = loc_of(ds, {}, "raw+vseqmatch", seq_len=5, k=3, anchor="end")
    est = list(replay(loc, ds.query))
    frames = np.array([e.frame for e in est if e.full_window])
    normed = [x / np.linalg.norm(x, axis=1, keepdims=True) for x in (q, r)]
    _, items = velocity_topk(*normed, 5, 3, frames - 4, loc.ref.match_starts, anchor="end", device="cpu")
    np.testing.assert_array_equal(np.stack([e.ranked for e in est if e.full_window]), items)


def test_errors(small):
    ds, models = small
    with pytest.raises(ConfigError, match="no online form"):
        loc_of(ds, models, "raw+grh")
    with pytest.raises(ConfigError, match="no online form"):
        loc_of(ds, models, "raw+grh-dh")
    with pytest.raises(ConfigError, match="needs an S_1 model"):
        loc_of(ds, {}, "hvpr")
    with pytest.raises(ConfigError, match="anchor"):
        loc_of(ds, models, "raw+seqmatch", anchor="middle")
    loc = loc_of(ds, models, "s1+seqmatch")
    with pytest.raises(ConfigError, match="dimension mismatch"):
        loc.step(np.zeros(5))
    with pytest.raises(ConfigError, match="NaN"):
        loc.step(np.full(12, np.nan))
    tiny = Dataset(Traverse(np.ones((3, 12), np.float32), np.zeros((3, 2))), ds.query, 1.0)
    with pytest.raises(ConfigError, match="longer than the map.s reference traverse"):
        loc_of(tiny, {}, "raw+seqmatch", seq_len=5)
