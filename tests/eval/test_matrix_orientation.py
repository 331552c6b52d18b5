"""Which reading of a given matrix was meant: the sense first, then transposition only beyond chance."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.eval.matrix import evaluate_matrix, open_matrix
from seqnet.eval.matrix.orientation import SQUARE_Z, choose_reading, sign_z

SINGLE = EvalConfig(methods=("single",), ks=(1, 5))


def aligned(n: int = 200, seed: int = 18) -> tuple[Dataset, np.ndarray]:
    """Two aligned traverses (frame i of each at place i, radius 1) and their similarity ``[Nq, Nr]``, one row
    per query: correctly oriented, but with this seed its transposed reading is a little better (R@1 0.625
    against 0.575, sign test z 1.5: noise), as Nordland's S of the report (0.393 against 0.373)."""
    rng = np.random.default_rng(seed)
    r = rng.standard_normal((n, 32))
    q = r + 1.6 * rng.standard_normal((n, 32))
    frames = np.arange(float(n))
    ds = Dataset(Traverse(r.astype(np.float32), frames, name="ref"), Traverse(q.astype(np.float32), frames,
                                                                             name="qry"), radius=1.0)
    return ds, q @ r.T


def warnings_of(caplog) -> str:
    return " ".join(r.getMessage() for r in caplog.records if r.levelname == "WARNING")


def test_a_correct_square_similarity_read_as_distances_is_told_the_sense_only(caplog):
    """The report's H3: the other sense's transposed reading was marginally better, so the hint named
    --transposed as well, and following it scored the traverses the other way round."""
    ds, s = aligned()
    with caplog.at_level("WARNING", logger="seqnet"):
        ev = evaluate_matrix(ds, s, SINGLE)  # similarities read as distances
    check = ev.results["matrix_check"]
    assert check["single_r@1"]["transposed, other sense"] > check["single_r@1"]["other sense"]  # the trap is set
    assert check["best_reading"] == "other sense"
    text = warnings_of(caplog)
    assert "(hint: pass --similarity (similarity=True in Python))" in text and "--transposed" not in text


def test_evaluate_matrix_applies_similarity_to_an_array(caplog):
    """`evaluate_matrix(ds, S, similarity=True)` used to read S as distances (R@1 0.000) and hint at flags."""
    ds, s = aligned()
    want = evaluate_matrix(ds, -s, SINGLE).results["methods"]["single"]["recall@1"]
    with caplog.at_level("WARNING", logger="seqnet"):
        got = evaluate_matrix(ds, s, SINGLE, similarity=True)
    assert got.results["methods"]["single"]["recall@1"] == want == pytest.approx(0.575)
    assert got.results["matrix_check"]["best_reading"] == "as given" and not warnings_of(caplog)
    turned = evaluate_matrix(ds, s.T, SINGLE, similarity=True, transposed=True)  # VPR_Tutorial's S = db @ q.T
    np.testing.assert_array_equal(turned.retrieved["single"], got.retrieved["single"])
    assert evaluate(ds, SINGLE).results["methods"]["single"]["recall@1"] > 0.5


def test_a_given_matrix_keeps_its_reading_and_refuses_a_contradiction(tmp_path):
    from seqnet.core.errors import ConfigError

    ds, s = aligned(60)
    np.save(tmp_path / "s.npy", s)
    given = open_matrix(tmp_path / "s.npy", ds, True)
    assert evaluate_matrix(ds, given, SINGLE).results["matrix_check"]["best_reading"] == "as given"
    with pytest.raises(ConfigError, match="opened with similarity=True"):
        evaluate_matrix(ds, given, SINGLE, similarity=False)
    with pytest.raises(ConfigError, match=r"is \[60, 59\] for 60 query and 60 reference frames"):
        evaluate_matrix(ds, s[:, :59], SINGLE)


def test_transposition_needs_the_sign_test_within_the_chosen_sense():
    """Against a naive loop over the four readings: the sense is the clearly better one, transposition is
    named only when its z within that sense reaches SQUARE_Z (or it is twice as good, and 0.1 above, at z 2)."""
    rng = np.random.default_rng(0)

    def hits(p):
        return rng.random(400) < p

    for _ in range(200):
        h = {k: hits(p) for k, p in zip(("as given", "other sense", "transposed", "transposed, other sense"),
                                        rng.choice([0.0, 0.02, 0.3, 0.35, 0.6, 0.65], 4), strict=True)}
        r1 = {k: v.mean() for k, v in h.items()}
        own, other = max(r1["as given"], r1["transposed"]), max(r1["other sense"], r1["transposed, other sense"])
        flip = other >= 2 * own and other >= own + 0.1
        plain, turned = ("other sense", "transposed, other sense") if flip else ("as given", "transposed")
        b = sum(x and not y for x, y in zip(h[turned], h[plain], strict=True))
        c = sum(y and not x for x, y in zip(h[turned], h[plain], strict=True))
        z = (b - c) / np.sqrt(b + c) if b + c else 0.0
        rt, rp = np.mean(h[turned]), np.mean(h[plain])
        want = turned if z >= SQUARE_Z or (rt >= 2 * rp and rt >= rp + 0.1 and z >= 2.0) else plain
        assert choose_reading(h) == want
    two = {"as given": hits(0.1), "other sense": hits(0.6)}  # not square: two readings only
    assert choose_reading(two) == "other sense"
    assert sign_z(two["other sense"], two["as given"]) > SQUARE_Z


def test_a_truly_transposed_square_matrix_is_still_named(caplog):
    """Traverses not aligned (the queries a permutation of the places): the transposed reading wins by far."""
    ds, s = aligned()
    perm = np.random.default_rng(1).permutation(len(ds.query))
    q = Traverse(ds.query.descriptors[perm], ds.query.positions[perm], name="qry")
    ds = Dataset(ds.reference, q, radius=1.0)
    with caplog.at_level("WARNING", logger="seqnet"):
        check = evaluate_matrix(ds, -s[perm].T, SINGLE).results["matrix_check"]
    assert check["best_reading"] == "transposed"
    assert "pass --transposed" in warnings_of(caplog) and "--similarity" not in warnings_of(caplog)


@pytest.mark.parametrize("n_ref", [150, 120])
def test_the_sense_warning_under_transposed_describes_the_reading_used(tmp_path, caplog, n_ref):
    """The report's L6: VPR_Tutorial's S [N_db, N_q] read with --transposed but without --similarity was
    described as "(distances, one row per query)"."""
    ds, s = aligned(n_ref)
    ds = Dataset(ds.reference, ds.query.subset(0, 120), radius=1.0)
    np.save(tmp_path / "S.npy", s[:120, :n_ref].T)
    given = open_matrix(tmp_path / "S.npy", ds, False, "all", True)
    with caplog.at_level("WARNING", logger="seqnet"):
        evaluate_matrix(ds, given, SINGLE)
    text = warnings_of(caplog)
    assert "read as given (distances, read transposed: one row per reference)" in text
    assert "(hint: pass --similarity (similarity=True in Python))" in text and "one row per query)" not in text


def test_read_matrix_carries_its_reading_so_flags_are_never_applied_twice(tmp_path, caplog):
    """Review M2: read_matrix(similarity=True) already gives distances; passing its output to evaluate_matrix
    with similarity=True negated it again (R@1 0.143 -> 0.036), and transposed=True on a square matrix turned
    it a second time, silently."""
    from seqnet.core.errors import ConfigError
    from seqnet.eval.matrix import read_matrix

    ds, s = aligned(60)
    np.save(tmp_path / "S.npy", s.T)  # VPR_Tutorial's S: similarities, one row per reference (square)
    d = read_matrix(tmp_path / "S.npy", ds, True, "all", True)
    want = evaluate_matrix(ds, -s, SINGLE).results["methods"]["single"]["recall@1"]
    with caplog.at_level("WARNING", logger="seqnet"):
        for flags in ({}, {"similarity": True}, {"transposed": True}, {"similarity": True, "transposed": True}):
            ev = evaluate_matrix(ds, d, SINGLE, **flags)
            assert ev.results["methods"]["single"]["recall@1"] == want, flags
            assert ev.results["matrix_check"]["best_reading"] == "as given"
    assert not warnings_of(caplog)
    with pytest.raises(ConfigError, match="read_matrix already applied similarity=True"):
        evaluate_matrix(ds, d, SINGLE, similarity=False)
    with pytest.raises(ConfigError, match="read_matrix already applied transposed=True"):
        evaluate_matrix(ds, d[:, :], SINGLE, transposed=False)  # a view keeps the reading
    plain = np.asarray(d)  # a plain array: the flags apply to it
    assert evaluate_matrix(ds, -plain, SINGLE, similarity=True).results["methods"]["single"]["recall@1"] == want


def test_every_reading_chosen_is_said(caplog):
    """Review M4: the decision and the warning used different tests, so "other sense" (chosen on its transposed
    layout) reached results.json with no warning, and a transposed reading 3x better on 12 queries was dropped."""
    from seqnet.eval.matrix.orientation import _warn_reading

    rng = np.random.default_rng(3)
    keys = ("as given", "transposed", "other sense", "transposed, other sense")
    n_chosen = 0
    for _ in range(300):
        n = int(rng.integers(8, 60))
        h = {k: rng.random(n) < p for k, p in zip(keys, rng.choice([0.0, 0.1, 0.2, 0.25, 0.45, 0.6], 4),
                                                   strict=True)}
        best = choose_reading(h)
        if best == "as given":
            continue
        n_chosen += 1
        caplog.clear()
        with caplog.at_level("WARNING", logger="seqnet"):
            _warn_reading(best, {k: float(v.mean()) for k, v in h.items()}, False, False,
                          sign_z(h[best], h["as given"]))
        assert warnings_of(caplog), (best, {k: v.mean() for k, v in h.items()})
    assert n_chosen > 50

    def first(k: int, n: int) -> np.ndarray:
        a = np.zeros(n, bool)
        a[:k] = True
        return a

    small = {"as given": first(2, 12), "transposed": first(6, 12), "other sense": first(0, 12),
             "transposed, other sense": first(0, 12)}
    assert choose_reading(small) == "transposed"  # 0.50 against 0.17 on 12 queries (z 2.0)
    noise = {**small, "transposed": first(3, 12)}  # one query more: noise, not named
    assert choose_reading(noise) == "as given"


@pytest.mark.parametrize("n", [24, 40])
def test_a_few_dozen_queries_still_name_a_transposed_or_wrong_sense_matrix(caplog, n):
    """Small samples: a truly transposed square matrix, or similarities read as distances, are named; the
    correct reading stays silent."""
    ds, s = aligned(n, seed=5)
    with caplog.at_level("WARNING", logger="seqnet"):
        assert evaluate_matrix(ds, -s, SINGLE).results["matrix_check"]["best_reading"] == "as given"
    assert not warnings_of(caplog)
    with caplog.at_level("WARNING", logger="seqnet"):
        assert evaluate_matrix(ds, s, SINGLE).results["matrix_check"]["best_reading"] == "other sense"
    assert "(hint: pass --similarity (similarity=True in Python))" in warnings_of(caplog)
    caplog.clear()
    perm = np.random.default_rng(1).permutation(n)
    ds = Dataset(ds.reference, Traverse(ds.query.descriptors[perm], ds.query.positions[perm], name="qry"),
                 radius=1.0)
    with caplog.at_level("WARNING", logger="seqnet"):
        check = evaluate_matrix(ds, -s[perm].T, SINGLE).results["matrix_check"]
    assert check["best_reading"] == "transposed", check
    assert "pass --transposed" in warnings_of(caplog)


def test_the_reading_warning_is_kept_in_the_results_and_a_flag_must_be_a_bool(caplog):
    """Hostile 52 L8: the orientation warning was logged only (results['warnings'] and results.json had none);
    L6: similarity='no' was read as True."""
    ds, s = aligned()
    with caplog.at_level("WARNING", logger="seqnet"):
        ev = evaluate_matrix(ds, s, SINGLE)  # similarities read as distances: said
    assert ev.results["warnings"] == [warnings_of(caplog)] and "warning" not in ev.results["matrix_check"]
    for bad in ("no", 0, 1.0):
        with pytest.raises(ConfigError, match="give True, False or None"):
            evaluate_matrix(ds, s, SINGLE, similarity=bad)
    assert evaluate_matrix(ds, s, SINGLE, similarity=np.True_).results["matrix_check"]["best_reading"] == "as given"


def test_a_matrix_read_the_wrong_way_is_not_also_called_shifted(monkeypatch):
    """Own-data hostile 52 L1: a similarity matrix read as distances also got 'the query positions look shifted
    ... build the dataset again' (8 of 67 top-1 answers), which --similarity made go: the reading is said alone."""
    import seqnet.eval.matrix as matrix

    monkeypatch.setattr(matrix, "shift_notice", lambda ev: "the query positions look shifted")
    ds, s = aligned()
    wrong = evaluate_matrix(ds, s, SINGLE)  # similarities read as distances
    assert wrong.results["matrix_check"]["best_reading"] == "other sense"
    assert not any("shifted" in w for w in wrong.results["warnings"]), wrong.results["warnings"]
    right = evaluate_matrix(ds, s, SINGLE, similarity=True)  # read right: a shift is said
    assert "the query positions look shifted" in right.results["warnings"]
