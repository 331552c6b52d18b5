"""Model-free k-NN evaluation on descriptor files runs in numpy (seqnet.reference.plain) without loading torch, with
the answers of the torch path."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from seqnet.eval import score as evaluate_module
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.methods.grammar import parse_method
from seqnet.reference import plain
from seqnet.reference.plain import runs_plain

PLAIN = ("single", "smoothing", "delta", "delta-paper")


def test_plain_and_torch_paths_agree(synth_dataset, monkeypatch):
    conf = EvalConfig(methods=PLAIN, seq_len=4, ks=(1, 5, 10), device="cpu")
    a = evaluate(synth_dataset, conf)
    monkeypatch.setattr(evaluate_module, "runs_plain", lambda *args: False)
    b = evaluate(synth_dataset, conf)
    for name in PLAIN:
        np.testing.assert_array_equal(a.retrieved[name], b.retrieved[name])
        np.testing.assert_allclose(a.scores[name], b.scores[name], rtol=1e-5, atol=1e-6)
        ra, rb = a.results["methods"][name], b.results["methods"][name]
        for key in ("recall@1", "recall@5", "recall@10", "queries", "no_positive"):
            assert ra.get(key) == rb.get(key), (name, key)
    assert a.results["config"]["device"] == b.results["config"]["device"] == "cpu"


def test_which_evaluations_run_plain(monkeypatch):
    monkeypatch.setattr(plain, "cuda_maybe", lambda: False)
    ms = [parse_method(n) for n in PLAIN]
    assert runs_plain(ms, None, "torch", "auto") and runs_plain(ms, {}, "torch", "cpu")
    assert not runs_plain(ms, None, "faiss", "auto")
    assert not runs_plain([*ms, parse_method("raw+seqmatch")], None, "torch", "auto")
    assert not runs_plain([parse_method("s1")], {"s1": object()}, "torch", "auto")
    assert not runs_plain(ms, {"s1": object()}, "torch", "auto")  # a model given: the torch path checks it
    assert not runs_plain([], None, "torch", "auto")
    monkeypatch.setattr(plain, "cuda_maybe", lambda: True)
    assert not runs_plain(ms, None, "torch", "auto") and runs_plain(ms, None, "torch", "cpu")


def write_route(root, n_ref=300, n_q=40, dim=16):
    """A dataset directory of frames along a route, 1-D positions (benchmarks/peers.py's layout)."""
    rng = np.random.default_rng(0)
    ref = np.cumsum(rng.standard_normal((n_ref, dim)), axis=0).astype(np.float32)
    src = np.sort(rng.choice(n_ref, n_q, replace=False))
    for side, x, pos in (("reference", ref, np.arange(n_ref)), ("query", ref[src] + 0.3, src)):
        (root / side).mkdir(parents=True)
        np.save(root / side / "descriptors.npy", x)
        np.save(root / side / "positions.npy", pos.reshape(-1, 1).astype(np.float64))
    (root / "dataset.json").write_text(json.dumps({"format": "seqnet-dataset/1", "name": "route", "radius": 2.0}))
    return root


def test_the_command_imports_no_torch_scipy_or_tqdm(tmp_path):
    """`seqnet eval --method single,smoothing,delta` on descriptor files with 1-D positions (a fresh interpreter)
    loads none of torch, scipy, tqdm, matplotlib."""
    ds = write_route(tmp_path / "ds")
    code = ("import sys; from seqnet.cli import main; "
            f"rc = main(['-q', 'eval', '--dataset', {str(ds)!r}, '--method', 'single,smoothing,delta', "
            f"'--ks', '1,5', '--device', 'cpu', '--json', {str(tmp_path / 'r.json')!r}]); "
            "print(*(m in sys.modules for m in ('torch', 'scipy', 'tqdm', 'matplotlib')), rc)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split()[-5:] == ["False", "False", "False", "False", "0"], out
    assert json.loads((tmp_path / "r.json").read_text())["methods"]["single"]["recall@1"] > 0.5


def test_single_on_rows_whose_squares_overflow(synth_dataset, monkeypatch):
    """float32 reference rows of 1e20: no inverse norms (squares overflow), so the normalised copy is searched;
    the same answers as the torch path."""
    import dataclasses

    ref = dataclasses.replace(synth_dataset.reference,
                              descriptors=synth_dataset.reference.descriptors * np.float32(1e20))
    ds = dataclasses.replace(synth_dataset, reference=ref)
    conf = EvalConfig(methods=("single",), ks=(1, 5), device="cpu")
    a = evaluate(ds, conf)
    monkeypatch.setattr(evaluate_module, "runs_plain", lambda *args: False)
    b = evaluate(ds, conf)
    np.testing.assert_array_equal(a.retrieved["single"], b.retrieved["single"])
