"""SeqMatch, candidate scoring, whole-map top-k and HVPR against naive loops."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.matching.hvpr import hvpr, rerank
from seqnet.matching.pairs import pick_strategy, window_scores
from seqnet.matching.seqmatch import seqmatch, seqmatch_topk
from seqnet.search.knn import knn


def naive_pair(q, r, a, b, L, reverse=False):
    return sum(float(np.linalg.norm(q[a + t] - r[b + (L - 1 - t if reverse else t)])) for t in range(L))


def naive_seqmatch(q, r, L, reverse=False):
    na, nb = len(q) - L + 1, len(r) - L + 1
    return np.array([[naive_pair(q, r, a, b, L, reverse) for b in range(nb)] for a in range(na)]).reshape(na, nb)


def stable_smallest(scores, k):
    """Indices of the k smallest scores, ties by lower index."""
    return sorted(range(len(scores)), key=lambda j: (scores[j], j))[:k]


@pytest.fixture
def qr(rng):
    return rng.standard_normal((17, 5)), rng.standard_normal((14, 5))


# ----------------------------------------------------------------------------- whole map


@pytest.mark.parametrize("L", [1, 2, 3, 5])
@pytest.mark.parametrize("reverse", [False, True])
def test_full_map_vs_loop(qr, L, reverse):
    q, r = qr
    m = seqmatch(q, r, L, reverse=reverse, device="cpu")
    assert isinstance(m, np.ndarray) and m.dtype == np.float64 and m.shape == (len(q) - L + 1, len(r) - L + 1)
    np.testing.assert_allclose(m, naive_seqmatch(q, r, L, reverse), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("block_bytes", [1, 300, 2000, None])
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("L", [1, 4])
def test_many_blocks_and_chunks(qr, block_bytes, reverse, L):
    q, r = qr
    q = np.concatenate([q, q[::-1], q])  # 51 query frames: several chunks
    # tile_bytes=1: the smallest tiles (one window pair each), many tiles per block
    m = seqmatch(q, r, L, reverse=reverse, device="cpu", block_bytes=block_bytes, tile_bytes=1)
    np.testing.assert_allclose(m, naive_seqmatch(q, r, L, reverse), rtol=1e-9, atol=1e-9)
    m = seqmatch(q, r, L, reverse=reverse, device="cpu", block_bytes=block_bytes)
    np.testing.assert_allclose(m, naive_seqmatch(q, r, L, reverse), rtol=1e-9, atol=1e-9)
    vals, items = seqmatch_topk(q, r, L, 3, np.arange(len(q) - L + 1), np.arange(len(r) - L + 1), reverse=reverse,
                                device="cpu", block_bytes=block_bytes)
    np.testing.assert_allclose(vals, np.sort(m, axis=1)[:, :3], rtol=1e-9, atol=1e-9)


def test_torch_input_returns_tensor_and_float32(qr):
    q, r = (torch.from_numpy(x.astype(np.float32)) for x in qr)
    m = seqmatch(q, r, 3, device="cpu")
    assert isinstance(m, torch.Tensor) and m.dtype == torch.float32 and m.device == q.device
    ref = naive_seqmatch(qr[0].astype(np.float32).astype(np.float64), qr[1].astype(np.float32).astype(np.float64), 3)
    np.testing.assert_allclose(m.numpy(), ref, rtol=1e-4, atol=1e-4)
    m64 = seqmatch(torch.from_numpy(qr[0]), torch.from_numpy(qr[1]), 3, device="cpu")
    assert m64.dtype == torch.float64


def test_numpy_float32_and_mixed_inputs(qr):
    q, r = qr
    m = seqmatch(q.astype(np.float32), r, 2, device="cpu")  # reference follows the query dtype
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, naive_seqmatch(q, r, 2), rtol=1e-4, atol=1e-4)
    m = seqmatch(q.astype(np.float16), r.astype(np.float16), 2, device="cpu")
    assert m.dtype == np.float32


def test_l_equal_to_traverse_length(qr):
    q, r = qr
    m = seqmatch(q[:6], r[:6], 6, device="cpu")
    assert m.shape == (1, 1)
    assert m[0, 0] == pytest.approx(naive_pair(q, r, 0, 0, 6))


def test_identical_sequences_score_zero(rng):
    x = rng.integers(-3, 4, (9, 4)).astype(np.float64)
    m = seqmatch(x, x, 3, device="cpu")
    np.testing.assert_allclose(np.diagonal(m), 0.0, atol=1e-12)


@pytest.mark.parametrize("bad", [0, -2, 18, 2.5, True])
def test_bad_seq_len(qr, bad):
    with pytest.raises(ConfigError, match="seq_len"):
        seqmatch(*qr, bad, device="cpu")


def test_bad_inputs(qr, rng):
    q, r = qr
    with pytest.raises(ConfigError, match="dimension mismatch"):
        seqmatch(q, rng.standard_normal((14, 4)), 3, device="cpu")
    with pytest.raises(ConfigError, match=r"\[N, D\]"):
        seqmatch(q[0], r, 1, device="cpu")
    with pytest.raises(ConfigError, match="longer than the traverse"):
        seqmatch(np.zeros((0, 5)), r, 1, device="cpu")


@settings(max_examples=40, deadline=None)
@given(nq=st.integers(1, 12), nr=st.integers(1, 12), d=st.integers(1, 4), L=st.integers(1, 5),
       reverse=st.booleans(), block_bytes=st.sampled_from([None, 1, 100]), seed=st.integers(0, 2**16))
def test_seqmatch_property(nq, nr, d, L, reverse, block_bytes, seed):
    rng = np.random.default_rng(seed)
    q, r = rng.standard_normal((nq, d)), rng.standard_normal((nr, d))
    if L > min(nq, nr):
        with pytest.raises(ConfigError):
            seqmatch(q, r, L, device="cpu")
        return
    m = seqmatch(q, r, L, reverse=reverse, device="cpu", block_bytes=block_bytes)
    np.testing.assert_allclose(m, naive_seqmatch(q, r, L, reverse), rtol=1e-9, atol=1e-9)


# ----------------------------------------------------------------------------- candidates


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("as_torch", [False, True])
def test_candidates_vs_loop(qr, rng, reverse, as_torch):
    q, r = qr
    L = 3
    na, nb = len(q) - L + 1, len(r) - L + 1
    cand = rng.integers(-1, nb, (na, 4))
    cand[0] = -1  # a row without any candidate
    args = (torch.from_numpy(q), torch.from_numpy(r), L, torch.from_numpy(cand)) if as_torch else (q, r, L, cand)
    s = seqmatch(*args, reverse=reverse, device="cpu", block_bytes=200)
    s = s.numpy() if as_torch else s
    assert s.shape == (na, 4)
    for a in range(na):
        for j, b in enumerate(cand[a]):
            expected = np.inf if b < 0 else naive_pair(q, r, a, b, L, reverse)
            assert s[a, j] == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_candidates_agree_with_full_map(qr):
    q, r = qr
    full = seqmatch(q, r, 4, device="cpu")
    cand = np.tile(np.arange(full.shape[1]), (full.shape[0], 1))
    np.testing.assert_allclose(seqmatch(q, r, 4, candidates=cand, device="cpu"), full, rtol=1e-9, atol=1e-9)


def test_candidates_empty_and_errors(qr):
    q, r = qr
    na = len(q) - 2
    assert seqmatch(q, r, 3, candidates=np.zeros((na, 0), int), device="cpu").shape == (na, 0)
    with pytest.raises(ConfigError, match="candidates must be"):
        seqmatch(q, r, 3, candidates=np.zeros((na - 1, 2), int), device="cpu")
    with pytest.raises(ConfigError, match="window starts must lie"):
        seqmatch(q, r, 3, candidates=np.full((na, 2), len(r) - 2), device="cpu")
    with pytest.raises(ConfigError, match="window starts must lie"):
        seqmatch(q, r, 3, candidates=np.full((na, 2), -2), device="cpu")
    with pytest.raises(ConfigError, match="integer"):
        seqmatch(q, r, 3, candidates=np.full((na, 2), 0.5), device="cpu")


def test_window_scores_validation(qr):
    q, r = (torch.from_numpy(x) for x in qr)
    with pytest.raises(ConfigError, match="query window starts"):
        window_scores(q, r, 3, torch.tensor([15]), torch.tensor([[0]]))
    with pytest.raises(ConfigError, match=r"\[M\]"):
        window_scores(q, r, 3, torch.tensor([0, 1]), torch.tensor([[0]]))


# ----------------------------------------------------------------------------- seqmatch_topk


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("block_bytes", [None, 100])
def test_seqmatch_topk_vs_loop(qr, rng, reverse, block_bytes):
    q, r = qr
    L = 3
    na, nb = len(q) - L + 1, len(r) - L + 1
    q_starts = rng.permutation(na)[:9]
    r_starts = np.sort(rng.permutation(nb)[:10])
    vals, items = seqmatch_topk(q, r, L, 4, q_starts, r_starts, reverse=reverse, device="cpu", block_bytes=block_bytes)
    full = naive_seqmatch(q, r, L, reverse)
    for m, a in enumerate(q_starts):
        row = full[a, r_starts]
        assert items[m].tolist() == stable_smallest(row.tolist(), 4)
        np.testing.assert_allclose(vals[m], row[items[m]], rtol=1e-9)


def test_seqmatch_topk_ties_lower_item_wins(rng):
    x = rng.integers(-3, 4, (8, 3)).astype(np.float64)
    ref = np.concatenate([x, x])  # every window appears twice: exact ties
    vals, items = seqmatch_topk(x, ref, 2, 2, np.array([0, 3]), np.arange(15), device="cpu")
    assert items.tolist() == [[0, 8], [3, 11]]
    np.testing.assert_allclose(vals, 0.0, atol=1e-12)


def test_seqmatch_topk_errors(qr):
    q, r = qr
    with pytest.raises(ConfigError, match="query window starts"):
        seqmatch_topk(q, r, 3, 2, np.array([0, 15]), np.arange(5), device="cpu")
    with pytest.raises(ConfigError, match="reference window starts"):
        seqmatch_topk(q, r, 3, 2, np.array([0]), np.array([12]), device="cpu")
    with pytest.raises(ConfigError, match="k must be"):
        seqmatch_topk(q, r, 3, 0, np.array([0]), np.array([1]), device="cpu")
    v, i = seqmatch_topk(q, r, 3, 2, np.zeros(0, np.int64), np.arange(5), device="cpu")
    assert v.shape == (0, 2)


# ----------------------------------------------------------------------------- HVPR


def naive_hvpr(sq, sr, q, r, L, q_starts, r_starts, top_k, reverse=False):
    items, scores = [], []
    for m in range(len(sq)):
        d = [float(np.linalg.norm(sq[m] - sr[j])) for j in range(len(sr))]
        short = stable_smallest(d, top_k)
        s = [naive_pair(q, r, q_starts[m], r_starts[j], L, reverse) for j in short]
        order = sorted(range(len(short)), key=lambda i: s[i])  # stable: ties keep shortlist order
        items.append([short[i] for i in order])
        scores.append([s[i] for i in order])
    return np.array(items), np.array(scores)


@pytest.mark.parametrize("reverse", [False, True])
def test_hvpr_vs_loop(rng, reverse):
    q, r = rng.standard_normal((20, 4)), rng.standard_normal((25, 4))
    L = 3
    q_starts, r_starts = np.arange(0, 18, 2), np.arange(0, 23)
    sq, sr = rng.standard_normal((len(q_starts), 6)), rng.standard_normal((len(r_starts), 6))
    matcher = "seqmatch-rev" if reverse else "seqmatch"
    scores, items = hvpr(sq, sr, q, r, L, q_starts, r_starts, top_k=5, matcher=matcher, device="cpu")
    n_items, n_scores = naive_hvpr(sq, sr, q, r, L, q_starts, r_starts, 5, reverse)
    np.testing.assert_array_equal(items, n_items)
    np.testing.assert_allclose(scores, n_scores, rtol=1e-9)


def test_hvpr_faiss_backend_matches(rng):
    q, r = rng.standard_normal((12, 4)).astype(np.float32), rng.standard_normal((12, 4)).astype(np.float32)
    sq, sr = rng.standard_normal((10, 6)).astype(np.float32), rng.standard_normal((10, 6)).astype(np.float32)
    starts = np.arange(10)
    a = hvpr(sq, sr, q, r, 3, starts, starts, top_k=4, device="cpu")
    b = hvpr(sq, sr, q, r, 3, starts, starts, top_k=4, backend="faiss", device="cpu")
    np.testing.assert_array_equal(a[1], b[1])


def test_hvpr_top_k_larger_than_references(rng):
    q, r = rng.standard_normal((6, 3)), rng.standard_normal((6, 3))
    scores, items = hvpr(q[:4], r[:4], q, r, 3, np.arange(4), np.arange(4), top_k=50, device="cpu")
    assert items.shape == (4, 4) and sorted(items[0].tolist()) == [0, 1, 2, 3]
    with pytest.raises(ConfigError, match="top_k"):
        hvpr(q[:4], r[:4], q, r, 3, np.arange(4), np.arange(4), top_k=0)


def test_rerank_missing_candidates_rank_last(rng):
    q, r = rng.standard_normal((10, 3)), rng.standard_normal((12, 3))
    cand = np.array([[2, -1, 0], [-1, -1, -1]])
    scores, items = rerank(q, r, 3, np.array([0, 5]), np.arange(10), cand, device="cpu")
    assert items[0, -1] == -1 and np.isinf(scores[0, -1]) and set(items[0, :2].tolist()) == {0, 2}
    assert items[1].tolist() == [-1, -1, -1] and np.isinf(scores[1]).all()
    assert scores[0, 0] == pytest.approx(min(naive_pair(q, r, 0, b, 3) for b in (0, 2)))


def test_rerank_errors(rng):
    q, r = rng.standard_normal((10, 3)), rng.standard_normal((12, 3))
    with pytest.raises(ConfigError, match="candidates must be reference items"):
        rerank(q, r, 3, np.array([0]), np.arange(4), np.array([[4]]), device="cpu")
    with pytest.raises(ConfigError, match="one row per query item"):
        rerank(q, r, 3, np.array([0, 1]), np.arange(4), np.array([[1]]), device="cpu")
    with pytest.raises(ConfigError, match="reference window starts"):
        rerank(q, r, 3, np.array([0]), np.array([10]), np.array([[0]]), device="cpu")


def test_hvpr_returns_full_ranking(rng):
    """With k > K the shortlist is re-ranked and the rest of the k-NN list follows (score inf)."""
    q, r = rng.standard_normal((10, 3)), rng.standard_normal((12, 3))
    sq, sr = rng.standard_normal((8, 5)), rng.standard_normal((10, 5))
    scores, items = hvpr(sq, sr, q, r, 3, np.arange(8), np.arange(10), top_k=3, k=7, device="cpu")
    _, ranked = knn(sq, sr, 7)
    assert items.shape == (8, 7)
    np.testing.assert_array_equal(items[:, 3:], ranked[:, 3:])
    assert np.isinf(scores[:, 3:]).all() and np.isfinite(scores[:, :3]).all()
    np.testing.assert_array_equal(np.sort(items[:, :3], axis=1), np.sort(ranked[:, :3], axis=1))
    assert (np.diff(scores[:, :3], axis=1) >= 0).all()


@pytest.mark.parametrize("col_block", [1, 2, 5, 7, None])
@pytest.mark.parametrize("reverse", [False, True])
def test_topk_streams_reference_blocks(rng, col_block, reverse):
    """Reference blocks of any size, read from a memory map, give the same top-k as the whole map."""
    q, r = rng.standard_normal((23, 6)), rng.standard_normal((31, 6))
    L, k = 3, 4
    q_starts, r_starts = np.arange(0, 21, 2), np.arange(0, 29)
    full = naive_seqmatch(q, r, L, reverse)[q_starts][:, r_starts]
    vals, items = seqmatch_topk(q, r, L, k, q_starts, r_starts, reverse=reverse, device="cpu", col_block=col_block,
                                block_bytes=200)
    np.testing.assert_allclose(vals, np.sort(full, axis=1)[:, :k], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.take_along_axis(full, items, 1), vals, rtol=1e-9, atol=1e-9)


def test_topk_from_memmap_and_float16(tmp_path, rng):
    q, r = rng.standard_normal((20, 8)).astype(np.float32), rng.standard_normal((40, 8)).astype(np.float32)
    np.save(tmp_path / "r.npy", r.astype(np.float16))
    r16 = np.load(tmp_path / "r.npy", mmap_mode="r")
    starts_q, starts_r = np.arange(18), np.arange(38)
    a = seqmatch_topk(q, r16, 3, 5, starts_q, starts_r, device="cpu", col_block=9)
    b = seqmatch_topk(q, r16.astype(np.float32), 3, 5, starts_q, starts_r, device="cpu")
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_allclose(a[0], b[0], rtol=1e-5)
    assert a[0].dtype == np.float32


def test_topk_ties_prefer_lower_start():
    q = np.zeros((4, 2))
    r = np.zeros((10, 2))  # every window scores 0: ties everywhere
    _, items = seqmatch_topk(q, r, 2, 3, np.arange(3), np.arange(9), device="cpu", col_block=2)
    assert items.tolist() == [[0, 1, 2]] * 3


@pytest.mark.parametrize("strategy", ["gather", "rows", "auto"])
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("block_bytes", [8, None])
def test_pair_strategies_vs_loop(rng, strategy, reverse, block_bytes):
    """Both ways of scoring candidate pairs equal the naive per-pair sum (shuffled query order, -1 slots)."""
    q, r = rng.standard_normal((25, 5)), rng.standard_normal((30, 5))
    L = 4
    q_starts = torch.as_tensor(rng.permutation(22)[:15])
    cand = torch.as_tensor(rng.integers(-1, 27, size=(15, 6)))
    got = window_scores(torch.from_numpy(q), torch.from_numpy(r), L, q_starts, cand, reverse, block_bytes, strategy)
    for m in range(15):
        for j in range(6):
            b = int(cand[m, j])
            want = np.inf if b < 0 else naive_pair(q, r, int(q_starts[m]), b, L, reverse)
            assert got[m, j].item() == pytest.approx(want, rel=1e-9, abs=1e-9)
    with pytest.raises(ConfigError, match="re-ranking strategy"):
        window_scores(torch.from_numpy(q), torch.from_numpy(r), L, q_starts, cand, strategy="magic")


def test_pick_strategy_by_cost():
    assert pick_strategy(n_queries=800, n_candidates=20, seq_len=5, n_ref=800) == "rows"
    assert pick_strategy(n_queries=1, n_candidates=20, seq_len=5, n_ref=1_000_000) == "gather"


@pytest.mark.parametrize("reverse", [False, True])
def test_scores_from_a_distance_matrix_equal_the_loop(qr, rng, reverse):
    from seqnet.matching.pairs import scores_from_distances

    q, r = qr
    L = 3
    dist = torch.cdist(torch.as_tensor(q, dtype=torch.float64), torch.as_tensor(r, dtype=torch.float64))
    q_starts = torch.as_tensor(rng.integers(0, len(q) - L + 1, 7))
    cand = torch.as_tensor(rng.integers(-1, len(r) - L + 1, (7, 4)))
    got = scores_from_distances(dist, L, q_starts, cand, reverse).numpy()
    for i, a in enumerate(q_starts.tolist()):
        for j, b in enumerate(cand[i].tolist()):
            want = np.inf if b < 0 else naive_pair(q, r, a, b, L, reverse)
            assert got[i, j] == pytest.approx(want, rel=1e-9), (i, j)
    with pytest.raises(ConfigError, match="inside the"):
        scores_from_distances(dist, L, q_starts, torch.full((7, 4), len(r) - 1), reverse)


def test_hvpr_reading_one_shared_matrix_equals_hvpr_apart(synth_dir, tmp_path, monkeypatch):
    """hvpr-single:raw+seqmatch reads its shortlist and its re-ranking from one frame-distance matrix when
    the re-ranking would compute distance rows anyway; the rankings are those of the two apart."""
    import json

    from seqnet.eval.evaluate import EvalConfig
    from seqnet.eval.evaluate import main as eval_main
    from seqnet.reference import traverse

    methods = ["hvpr-single:raw+seqmatch", "hvpr-single:raw+seqmatch-rev", "hvpr-smoothing:raw+seqmatch"]
    conf = EvalConfig(methods=methods, seq_len=4, ks=(1, 5, 20), top_k=150)
    shared = eval_main(conf, synth_dir, tmp_path / "shared.json", per_query=tmp_path / "shared.jsonl")
    calls = []
    monkeypatch.setattr(traverse.TraverseReference, "shared_distances", lambda self, f, q: calls.append(f))
    apart = eval_main(conf, synth_dir, tmp_path / "apart.json", per_query=tmp_path / "apart.jsonl")
    assert calls == ["single", "single"]  # asked for the two seqmatch entries (not the smoothing shortlist)
    a, b = json.loads(shared.path.read_text())["methods"], json.loads(apart.path.read_text())["methods"]
    assert {m: v["recall@5"] for m, v in a.items()} == {m: v["recall@5"] for m, v in b.items()}
    for x, y in zip((tmp_path / "shared.jsonl").read_text().splitlines(),
                    (tmp_path / "apart.jsonl").read_text().splitlines(), strict=True):
        rx, ry = json.loads(x), json.loads(y)
        assert rx["reference_indices"] == ry["reference_indices"]
        np.testing.assert_allclose(rx["scores"], ry["scores"], rtol=1e-5)


def test_seqmatch_says_rows_far_from_unit_norm_and_normalize_matches_unit_rows(caplog, monkeypatch):
    """seqmatch compared non-unit rows as given, unlike evaluate(), and said nothing (R@1 0.061 against 0.753)."""
    import logging

    import seqnet.core.log

    monkeypatch.setattr(seqnet.core.log, "_SAID", set())  # said once a process: another test may have said it
    rng = np.random.default_rng(3)
    qu, ru = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in rng.standard_normal((2, 12, 6)).astype(np.float32))
    qs, rs = (x * rng.uniform(0.3, 3, (12, 1)).astype(np.float32) for x in (qu, ru))
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        seqmatch(qs, rs, 3)
    assert "seqmatch: query row" in caplog.text and "normalize=True" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        out = seqmatch(qs, rs, 3, normalize=True)
        plain = seqmatch(qs, rs, 3, normalize=False)
        unit_rows = seqmatch(qu, ru, 3)
    assert not caplog.records
    assert isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, unit_rows, atol=1e-5)
    np.testing.assert_allclose(out, naive_seqmatch(qu, ru, 3), atol=1e-4)
    np.testing.assert_allclose(plain, naive_seqmatch(qs, rs, 3), atol=1e-4)


def test_readme_seqmatch_example_is_silent(caplog):
    """The README passed non-unit np.random.rand rows to seqmatch (now: unit rows, no warning)."""
    import logging
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    lines = [ln for ln in re.search(r"```python\n(.*?)```", text, re.S).group(1).splitlines()
             if ln.startswith(("import numpy", "unit =", "q, r =", "M =", "M_rev ="))]
    assert any(ln.startswith("M =") for ln in lines)
    env = {"seqmatch": seqmatch}
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        exec("\n".join(lines), env)  # noqa: S102 - the README's own lines
    assert env["M"].shape == (296, 396) and not caplog.records
