"""docs/extending.md's worked example, run as it is written: a matcher added by one table entry works in the
evaluation (whole map and HVPR re-ranking, checked against a plain loop) and in the online localiser (equal
to the offline causal evaluation), and is refused where it declares no form (a distance matrix)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.matching.registry import SEQUENCE_MATCHERS
from seqnet.methods.grammar import parse_method
from seqnet.sequence.windows import window_starts

PAGE = Path(__file__).resolve().parents[2] / "docs" / "extending.md"
L = 4


@pytest.fixture
def registered(monkeypatch):
    """The page's python block executed; the table restored afterwards."""
    block = re.search(r"```python\n(.*?)```", PAGE.read_text(), re.S).group(1)
    monkeypatch.setattr("seqnet.matching.registry.SEQUENCE_MATCHERS", SEQUENCE_MATCHERS)
    saved = dict(SEQUENCE_MATCHERS)
    exec(compile(block, str(PAGE), "exec"), {"__name__": "docs_extending"})
    assert "seqmatch-sq" in SEQUENCE_MATCHERS
    yield
    SEQUENCE_MATCHERS.clear()
    SEQUENCE_MATCHERS.update(saved)


@pytest.fixture(scope="module")
def route():
    return make_synthetic(places=100, dim=8, seed=3).split("test")


def naive_best(q: np.ndarray, r: np.ndarray, q_items: np.ndarray, mode: str) -> np.ndarray:
    """For each query item, the reference frame whose L-window has the lowest sum of squared distances."""
    qs, _ = window_starts(len(q), L, mode)
    rs, rok = window_starts(len(r), L, mode)
    r_items = np.flatnonzero(rok)
    best = []
    for i in q_items:
        scores = [sum(float(((q[qs[i] + t] - r[rs[j] + t]) ** 2).sum()) for t in range(L)) for j in r_items]
        best.append(r_items[int(np.argmin(scores))])
    return np.array(best)


def test_the_pages_matcher_runs_in_the_evaluation(registered, route):
    conf = EvalConfig(methods=("raw+seqmatch-sq", "hvpr-single:raw+seqmatch-sq"), seq_len=L, ks=(1, 5), top_k=100,
                      device="cpu")
    ev = evaluate(route, conf)
    view = ev.view("raw+seqmatch-sq")
    want = naive_best(route.query.descriptors, route.reference.descriptors, view.q_items, "centred")
    np.testing.assert_array_equal(view.r_items[ev.retrieved["raw+seqmatch-sq"][:, 0]], want)
    # HVPR over a shortlist as long as the map re-ranks everything: the same first answer as the whole map
    np.testing.assert_array_equal(ev.retrieved["hvpr-single:raw+seqmatch-sq"][:, 0],
                                  ev.retrieved["raw+seqmatch-sq"][:, 0])
    assert ev.results["methods"]["raw+seqmatch-sq"]["recall@5"] > 0.5


def test_the_pages_matcher_online_equals_offline(registered, route):
    method = "raw+seqmatch-sq"
    ev = evaluate(route, EvalConfig(methods=(method,), seq_len=L, window="causal", ks=(3,), device="cpu"))
    loc = dataset_localizer(route, {}, LocalizeConfig(method=method, seq_len=L, k=3, device="cpu"))
    est = [e for e in replay(loc, route.query) if e.full_window]
    assert [e.frame for e in est] == ev.view(method).q_items.tolist()
    np.testing.assert_array_equal(np.stack([e.ranked for e in est]), ev.retrieved[method])


def test_a_matcher_without_a_matrix_form_is_refused_on_a_matrix(registered):
    from seqnet.reference.matrix import MatrixReference

    assert not SEQUENCE_MATCHERS["seqmatch-sq"].on_matrix
    with pytest.raises(ConfigError, match="needs descriptors"):
        MatrixReference.check_method(None, parse_method("raw+seqmatch-sq"))  # reads the table, not self
