"""Recall@K against a naive loop, exclusion of queries without a positive, and edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.metrics.recall import GroundTruth, check_radius, recall, recall_at_k, recall_curve


def naive_recall(retrieved, q_pos, r_pos, radius, ks):
    out, n_pos, found = {}, 0, {k: 0 for k in ks}
    for m in range(len(q_pos)):
        if not any(np.linalg.norm(r_pos[j] - q_pos[m]) <= radius for j in range(len(r_pos))):
            continue
        n_pos += 1
        for k in ks:
            top = [j for j in retrieved[m][:k] if j >= 0]
            if any(np.linalg.norm(r_pos[j] - q_pos[m]) <= radius for j in top):
                found[k] += 1
    for k in ks:
        out[f"recall@{k}"] = found[k] / n_pos if n_pos else float("nan")
    out["queries"] = n_pos
    out["no_positive"] = len(q_pos) - n_pos
    return out


def assert_same(a, b):
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(b[key], float) and math.isnan(b[key]):
            assert math.isnan(a[key]), key
        else:
            assert a[key] == pytest.approx(b[key]), key


@pytest.mark.parametrize("dims", [1, 2])
def test_recall_vs_loop(rng, dims):
    r_pos = rng.uniform(0, 50, (40, dims))
    q_pos = rng.uniform(-10, 60, (30, dims))  # some queries have no reference within the radius
    retrieved = np.array([rng.permutation(40)[:25] for _ in range(30)])
    retrieved[3, 5] = -1
    ks = (1, 5, 10, 20, 25)
    res = recall_at_k(retrieved, q_pos, r_pos, 3.0, ks)
    assert_same(res, naive_recall(retrieved, q_pos, r_pos, 3.0, ks))
    truth = GroundTruth(q_pos, r_pos, 3.0)  # the evaluation's own recall scores a K above the columns as before
    assert_same(recall(retrieved, truth, (*ks, 100)), naive_recall(retrieved, q_pos, r_pos, 3.0, (*ks, 100)))
    assert res["no_positive"] > 0 and res["queries"] + res["no_positive"] == 30


def test_recall_hand_example():
    r_pos = np.array([[0.0], [10.0], [20.0], [30.0]])
    q_pos = np.array([[0.5], [19.0], [100.0]])  # the last query has no positive
    retrieved = np.array([[1, 0, 2], [0, 1, 3], [0, 1, 2]])
    res = recall_at_k(retrieved, q_pos, r_pos, 1.0, ks=(1, 2, 3))
    assert res == {"recall@1": 0.0, "recall@2": 0.5, "recall@3": 0.5, "queries": 2, "no_positive": 1}


def test_radius_boundary_is_inclusive():
    r_pos = np.array([[0.0, 0.0]])
    q_pos = np.array([[3.0, 4.0]])  # exactly 5 away
    assert recall_at_k(np.array([[0]]), q_pos, r_pos, 5.0, ks=(1,))["recall@1"] == 1.0
    res = recall_at_k(np.array([[0]]), q_pos, r_pos, 4.999, ks=(1,))
    assert res["queries"] == 0 and math.isnan(res["recall@1"])


def test_k_larger_than_list_uses_whole_list():
    """Every reference retrieved (2 of 2): R@100 is well defined, as the evaluation scores a short reference."""
    r_pos = np.arange(2.0)[:, None]
    res = recall_at_k(np.array([[1, 0]]), np.array([[0.0]]), r_pos, 0.5, ks=(1, 2, 100))
    assert res["recall@1"] == 0.0 and res["recall@2"] == 1.0 and res["recall@100"] == 1.0
    res = recall(np.array([[4, 0]]), GroundTruth(np.array([[0.0]]), np.arange(5.0)[:, None], 0.5), (1, 2, 100))
    assert res["recall@100"] == 1.0  # the evaluation's recall: the whole list


def five_of_hundred():
    """5 columns retrieved of 100 references, every one wrong but column 5 of half the queries (hunt F3)."""
    pos = np.stack([np.arange(100) * 100.0, np.zeros(100)], 1)
    ret = np.full((100, 5), 99)
    ret[:, 4] = np.where(np.arange(100) < 50, np.arange(100), 99)
    return ret, pos


def test_k_above_the_columns_retrieved_is_refused():
    """R@10 = R@20 = R@5 = 0.51 from 5 columns of 100 references, without a word (hunt F3)."""
    ret, pos = five_of_hundred()
    with pytest.raises(ConfigError, match=r"K 10, 20 above the 5 columns retrieved \(of 100 references\).*"
                                          r"knn\(\.\.\., k=20\).*ks= up to 5"):
        recall_at_k(ret, pos, pos, 25, ks=(1, 5, 10, 20))
    assert recall_at_k(ret, pos, pos, 25, ks=(1, 5))["recall@5"] == 0.51


def test_default_ks_stop_at_the_columns_retrieved(caplog):
    """The default ks after knn(k=3) gave an R@100 from 3 columns; now the Ks above 3 are left out, said once."""
    ret, pos = five_of_hundred()
    with caplog.at_level("WARNING", logger="seqnet"):
        res = recall_at_k(ret[:, 2:], pos, pos, 25)
    assert [k for k in res if k.startswith("recall@")] == ["recall@1"] and res["recall@1"] == 0.01
    assert "R@5, R@10, R@20, R@100 left out: the 3 columns retrieved (of 100 references)" in caplog.text
    assert "knn(..., k=100)" in caplog.text


def test_empty_inputs():
    res = recall_at_k(np.zeros((0, 5), np.int64), np.zeros((0, 2)), np.zeros((3, 2)), 1.0)
    assert res["queries"] == 0 and res["no_positive"] == 0 and math.isnan(res["recall@1"])
    res = recall_at_k(np.zeros((2, 0), np.int64), np.zeros((2, 2)), np.zeros((3, 2)), 1.0, ks=(1,))
    assert res == {"recall@1": 0.0, "queries": 2, "no_positive": 0}  # nothing retrieved: nothing found
    res = recall_at_k(np.zeros((2, 0), np.int64), np.zeros((2, 2)), np.zeros((3, 2)), 1.0)
    assert res["recall@100"] == 0.0  # no column: a method that found nothing, not a short retrieval
    res = recall_at_k(np.full((2, 1), -1), np.zeros((2, 2)), np.zeros((0, 2)), 1.0, ks=(1,))
    assert res["queries"] == 0 and res["no_positive"] == 2


def test_one_dimensional_inputs():
    res = recall_at_k(np.array([1, 0]), np.array([0.0, 5.0]), np.array([0.0, 5.0]), 1.0, ks=(1,))
    assert res["recall@1"] == 0.0 and res["queries"] == 2


@pytest.mark.parametrize("bad", [0, -1, float("nan"), float("inf"), "far", None])
def test_bad_radius(bad):
    with pytest.raises(ConfigError, match="radius"):
        recall_at_k(np.zeros((1, 1), int), np.zeros((1, 2)), np.zeros((1, 2)), bad)
    with pytest.raises(ConfigError, match="radius"):
        check_radius(bad)


def test_bad_arguments():
    q, r = np.zeros((2, 2)), np.zeros((3, 2))
    with pytest.raises(ConfigError, match="K must be"):
        recall_at_k(np.zeros((2, 1), int), q, r, 1.0, ks=(0, 1))
    with pytest.raises(ConfigError, match="K must be"):
        recall_at_k(np.zeros((2, 1), int), q, r, 1.0, ks=())
    with pytest.raises(ConfigError, match="one row per query"):
        recall_at_k(np.zeros((3, 1), int), q, r, 1.0)
    with pytest.raises(ConfigError, match="retrieved indices"):
        recall_at_k(np.full((2, 1), 3), q, r, 1.0)
    with pytest.raises(ConfigError, match="-D"):
        recall_at_k(np.zeros((2, 1), int), q, np.zeros((3, 1)), 1.0)


def test_recall_curve_monotone(rng):
    r_pos = rng.uniform(0, 20, (30, 2))
    q_pos = rng.uniform(0, 20, (15, 2))
    retrieved = np.array([rng.permutation(30)[:10] for _ in range(15)])
    curve = recall_curve(retrieved, GroundTruth(q_pos, r_pos, 2.0), k_max=12)
    assert curve.shape == (12,) and (np.diff(curve) >= 0).all()
    assert curve[0] == recall_at_k(retrieved, q_pos, r_pos, 2.0, ks=(1,))["recall@1"]


@settings(max_examples=40, deadline=None)
@given(m=st.integers(0, 8), n=st.integers(1, 10), k=st.integers(1, 6), seed=st.integers(0, 2**16))
def test_recall_property(m, n, k, seed):
    rng = np.random.default_rng(seed)
    r_pos = rng.integers(0, 10, (n, 1)).astype(float)  # integer positions: many exact boundary cases
    q_pos = rng.integers(0, 12, (m, 1)).astype(float)
    retrieved = rng.integers(-1, n, (m, k))
    ks = (1, 2, 5)
    naive = naive_recall(retrieved, q_pos, r_pos, 1.0, ks)
    assert_same(recall(retrieved, GroundTruth(q_pos, r_pos, 1.0), ks), naive)
    scored = tuple(x for x in ks if x <= k or k >= n)  # recall_at_k refuses a K above k columns of n references
    want = {key: v for key, v in naive.items() if not key.startswith("recall@") or int(key[7:]) in scored}
    assert_same(recall_at_k(retrieved, q_pos, r_pos, 1.0, scored), want)


def test_recall_denominator_positives_or_all_vs_loop(rng):
    """``positives`` (the original code's): queries without a correct reference left out; ``all`` (as
    VPR-methods-evaluation): they count as failures. Checked against a loop on random data."""
    from seqnet.metrics.recall import recall

    q, r = rng.uniform(0, 30, (60, 2)), rng.uniform(0, 30, (50, 2))
    retrieved = np.argsort(rng.random((60, 50)), axis=1)[:, :10]
    truth = GroundTruth(q, r, 2.5)
    has = [bool((np.linalg.norm(r - q[i], axis=1) <= 2.5).any()) for i in range(60)]
    assert 0 < sum(has) < 60  # some queries have no reference within the radius
    pos, every = recall(retrieved, truth, (1, 5), "positives"), recall(retrieved, truth, (1, 5), "all")
    for k in (1, 5):
        found = [any(np.linalg.norm(r[j] - q[i]) <= 2.5 for j in retrieved[i, :k]) for i in range(60)]
        assert pos[f"recall@{k}"] == pytest.approx(sum(found) / sum(has))
        assert every[f"recall@{k}"] == pytest.approx(sum(found) / 60)
    assert pos["queries"] == sum(has) and every["queries"] == 60 and every["no_positive"] == 60 - sum(has)
    assert recall(retrieved, truth, (1,))["recall@1"] == pos["recall@1"]  # positives is the default
    with pytest.raises(ConfigError, match="recall denominator 'some' is not one of positives, all"):
        recall(retrieved, truth, (1,), "some")


def test_recall_denominator_in_results_and_table_header():
    from seqnet.data.synth import make_synthetic
    from seqnet.eval.evaluate import EvalConfig, evaluate
    from seqnet.report.tables import format_markdown, format_table

    ds = make_synthetic(places=150, dim=8, seed=0).split("test")
    conf = EvalConfig(methods=("single",), seq_len=1, device="cpu", ks=(1, 5), radius=0.3)
    a, b = evaluate(ds, conf), evaluate(ds, conf.replace(recall_denominator="all"))
    ra, rb = a.results["methods"]["single"], b.results["methods"]["single"]
    assert b.results["config"]["recall_denominator"] == "all" and rb["recall_denominator"] == "all"
    assert a.results["config"]["recall_denominator"] == "positives" and ra["recall_denominator"] == "positives"
    n = ra["queries"] + ra["no_positive"]
    assert ra["no_positive"] > 0 and rb["recall@1"] == pytest.approx(ra["recall@1"] * ra["queries"] / n)
    assert format_table(b.results["methods"], (1,)).splitlines()[0].startswith("method (R@K ÷ all)")
    assert format_markdown(a.results["methods"], (1,)).startswith("| method (R@K ÷ positives) |")
    assert format_table({"old": {"recall@1": 0.5, "queries": 3}}, (1,)).startswith("method (R@K ÷ positives)")


def test_recall_over_all_queries_without_any_positive_is_zero():
    """Under ``all`` every query counts: no positive anywhere is recall 0, not NaN (``positives``: NaN)."""
    from seqnet.metrics.recall import recall

    truth = GroundTruth(np.array([[0.0, 0], [1, 0]]), np.array([[100.0, 0], [200, 0]]), 1.0)
    assert recall(np.array([[0], [1]]), truth, ks=(1,), denominator="all")["recall@1"] == 0.0
    assert np.isnan(recall(np.array([[0], [1]]), truth, ks=(1,))["recall@1"])


def test_the_names_that_lived_in_descriptors_still_import():
    from seqnet.sequence import descriptors
    from seqnet.sequence.model import SeqNet

    assert descriptors.SeqNet is SeqNet and descriptors.delta_orig is descriptors.delta_paper
    with pytest.raises(AttributeError):
        descriptors.nosuch  # noqa: B018


def test_ground_truth_pairs_and_of_equal_a_naive_loop():
    from seqnet.data.positives import Positives

    rng = np.random.default_rng(3)
    q, r = rng.uniform(0, 10, (30, 2)), rng.uniform(0, 10, (40, 2))
    t = GroundTruth(q, r, 1.5)
    naive = [(i, j) for i in range(30) for j in range(40) if np.linalg.norm(q[i] - r[j]) <= 1.5]
    assert list(zip(*(a.tolist() for a in t.pairs()), strict=True)) == naive
    for i in range(30):
        assert t.of(i).tolist() == [j for a, j in naive if a == i]
    explicit = GroundTruth(q[:3], r[:4], 1.0, positives=Positives.from_lists([[2, 0], [], [3]]))
    assert [x.tolist() for x in explicit.pairs()] == [[0, 0, 2], [0, 2, 3]] and explicit.of(1).tolist() == []


def test_a_wider_radius_with_explicit_positives_widens_around_the_positives() -> None:
    """``--extra-radius`` with explicit positives: the references within the radius of a positive (reference
    positions only), against a naive loop; the query's own positions (another numbering) are never read, and
    recall never drops as the radius grows."""
    from seqnet.data.positives import Positives

    rng = np.random.default_rng(0)
    for trial in range(30):
        n_q, n_r = int(rng.integers(1, 12)), int(rng.integers(1, 30))
        lists = [sorted(set(rng.integers(0, n_r, int(rng.integers(0, 3))).tolist())) for _ in range(n_q)]
        r_pos = rng.integers(0, 40, (n_r, 1)).astype(float) if trial % 2 else rng.normal(size=(n_r, 2)) * 5
        q_pos = rng.normal(size=(n_q, r_pos.shape[1])) * 1000  # another numbering: never comparable
        truth = GroundTruth(q_pos, r_pos, 1.0, Positives.from_lists(lists))
        retrieved = rng.integers(-1, n_r, (n_q, 5))
        before = recall(retrieved, truth, (1, 5))
        for radius in (0.01, 1.0, 2.5, 7.0):
            wide = truth.within(radius)
            for m in range(n_q):
                want = sorted({j for p in lists[m] for j in range(n_r)
                               if np.linalg.norm(r_pos[j] - r_pos[p]) <= radius})
                assert wide.of(m).tolist() == want
            assert wide.radius == radius
            after = recall(retrieved, wide, (1, 5))
            assert after["queries"] == before["queries"]
            if before["queries"]:
                assert after["recall@1"] >= before["recall@1"] and after["recall@5"] >= before["recall@5"]
            before = after
    plain = GroundTruth(np.zeros((2, 1)), np.arange(4.0)[:, None], 1.0)
    assert plain.within(2.0).radius == 2.0 and plain.within(2.0).positives is None


def test_no_explicit_positive_among_the_references_does_not_blame_the_radius():
    """With explicit positives the radius plays no part: the error says so and points at the positives and the
    split's reference range (it hinted at the radius and its unit)."""
    from seqnet.data.positives import Positives
    from seqnet.metrics.recall import ground_truth

    pos = Positives.from_lists([[], [], []])
    with pytest.raises(ConfigError, match="radius plays no part with explicit positives: check that the positives"):
        ground_truth(np.zeros((3, 1)), np.zeros((4, 1)), 1.0, pos)
    with pytest.raises(ConfigError, match="check the radius and its unit"):
        ground_truth(np.zeros((3, 1)), np.full((4, 1), 9.0), 1.0)


@pytest.mark.parametrize("ks", [5, np.int64(5), (5,), np.array([5])])
def test_one_integer_k_is_that_k(rng, ks):
    """recall_at_k(..., ks=5) raised TypeError: 'int' object is not iterable."""
    pos = rng.uniform(0, 100, (40, 2))
    ret = np.argsort(rng.random((40, 40)), 1)[:, :5]
    naive = np.mean([any(np.linalg.norm(pos[j] - pos[m]) <= 30 for j in ret[m]) for m in range(40)])
    out = recall_at_k(ret, pos, pos, 30.0, ks)
    assert set(out) == {"recall@5", "queries", "no_positive"} and out["recall@5"] == pytest.approx(naive)


@pytest.mark.parametrize("ks", [True, "1,5", b"1", 2.0, [1.5], [None], [True]])  # None alone: the default
def test_ks_that_are_no_integers_are_refused(ks):
    q = np.zeros((2, 2))
    with pytest.raises(ConfigError, match=r"every K must be an integer >= 1: ks is one K or a sequence"):
        recall_at_k(np.zeros((2, 1), int), q, q, 1.0, ks=ks)


def test_ragged_retrieved_is_one_line_naming_the_row_lengths():
    """Rows of different lengths raised numpy's ValueError (inhomogeneous shape)."""
    q = np.zeros((4, 2))
    with pytest.raises(ConfigError, match=r"retrieved must be \[M, K\].*rows of lengths 1, 2 \(hint: pad the short "
                                          r"rows with -1"):
        recall_at_k([[1, 2], [3], [0], [0]], q, q, 1.0, (1,))
