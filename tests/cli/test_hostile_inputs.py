"""A hostile user's battery: bad options, garbage files, OS failures and races, over every command and the API.

Every case must end in exit code 2 (bad input) or 1 (a failing environment), exactly one line on
stderr naming the problem, no traceback, and no file the user had lost or changed.
"""

from __future__ import annotations

import errno
import json
import multiprocessing
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from seqnet.cli import main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic


def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG that declares width x height pixels but holds almost no data (a decompression bomb)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16))
                     + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """Read-only inputs shared by the cases (each case writes only under its own tmp_path)."""
    root = tmp_path_factory.mktemp("hostile")
    save_dataset(make_synthetic(places=150, dim=8, seed=3), root / "ds")
    (root / "imgs").mkdir()
    rng = np.random.default_rng(0)
    for i in range(4):
        Image.fromarray((rng.random((16, 32, 3)) * 255).astype(np.uint8)).save(root / "imgs" / f"{i}.png")
    _png_header_only(root / "bomb.png", 60000, 60000)
    (root / "bombs").mkdir()
    shutil.copy(root / "bomb.png", root / "bombs" / "b.png")
    (root / "notes.txt").write_text("a user's file")
    (root / "garbage.npy").write_bytes(b"garbage bytes")
    (root / "garbage.h5").write_bytes(b"not hdf5")
    (root / "garbage.pt").write_bytes(b"not a checkpoint")
    (root / "latin1.csv").write_bytes(b"name,frame\n\xe9t\xe9.png,0\n")
    (root / "short_row.csv").write_text("name,frame\na.png,0\n1\n")
    (root / "dup.csv").write_text("name,frame\n0.png,0\n0.png,1\n")
    (root / "ok.csv").write_text("name,frame\n" + "".join(f"{i}.png,{i}\n" for i in range(4)))
    (root / "text.db").write_text("not a mat file")
    (root / "empty.db").write_bytes(b"")
    np.save(root / "d4.npy", rng.standard_normal((4, 8)).astype(np.float32))
    np.save(root / "d4_16.npy", rng.standard_normal((4, 16)).astype(np.float32))
    np.save(root / "zeros.npy", np.zeros((4, 8), np.float32))
    np.save(root / "nan.npy", np.full((4, 8), np.nan, np.float32))
    np.save(root / "empty.npy", np.zeros((0, 8), np.float32))
    np.save(root / "strings.npy", np.array([["a"] * 8] * 4))
    (root / "empty.txt").write_text("")
    (root / "names4.txt").write_text("0.png\n1.png\n2.png\n3.png\n")
    for stem in ("d4", "d4_16", "zeros", "nan"):  # names beside the .npy, as seqnet describe writes them: rows of
        (root / f"{stem}.names.txt").write_text("0.png\n1.png\n2.png\n3.png\n")  # ok.csv are paired by name
    (root / "bad_positives.json").write_text('{"not": "a list"}')
    (root / "flags").mkdir()
    return root


def run(capsys, argv: list[str], code: int, pattern: str) -> str:
    capsys.readouterr()
    rc = main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == code, (rc, err)
    assert len(lines) == 1, err
    assert "Traceback" not in err and "\r" not in err
    assert pattern in lines[0], lines[0]
    return lines[0]


# ----------------------------------------------------------------------------- bad option values (parse time)

BAD_OPTIONS = [
    # eval
    *[(["eval", "--dataset", "{ds}", opt, val], opt) for opt, val in [
        ("--seq-len", "0"), ("--seq-len", "-1"), ("--seq-len", "x"), ("--seq-len", "1.5"), ("--rerank-seq-len", "0"),
        ("--radius", "0"), ("--radius", "-1"), ("--radius", "nan"), ("--radius", "inf"), ("--radius", "x"),
        ("--extra-radius", "0"), ("--top-k", "0"), ("--top-k", "x"), ("--ks", "0"), ("--ks", "1,x"),
        ("--window", "middle"), ("--backend", "annoy")]],
    # train
    *[(["train", "--dataset", "{ds}", "--out", "{out}/run", opt, val], opt) for opt, val in [
        ("--seq-len", "0"), ("--w", "0"), ("--lr", "0"), ("--lr", "-1"), ("--lr", "nan"), ("--momentum", "-1"),
        ("--weight-decay", "-1"), ("--lr-step", "0"), ("--lr-gamma", "0"), ("--margin", "0"), ("--batch-size", "0"),
        ("--epochs", "0"), ("--patience", "0"), ("--seed", "-1"), ("--n-negatives", "0"), ("--n-neg-sample", "0"),
        ("--cache-refresh", "-1"), ("--pos-radius", "0"), ("--neg-radius", "-1"), ("--optimizer", "rmsprop"),
        ("--window", "x"), ("--out-dims", "0")]],
    # synth
    *[(["synth", "{out}/s", opt, val], opt) for opt, val in [
        ("--places", "5"), ("--dim", "0"), ("--noise", "0"), ("--nuisance", "-1"), ("--seed", "-1")]],
    # describe
    *[(["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.h5", opt, val], opt) for opt, val in [
        ("--crop-bottom", "-1"), ("--batch-size", "0"), ("--dim", "0"), ("--patch", "-1"), ("--gem-p", "0"),
        ("--clusters", "0"), ("--fit-max", "0"), ("--backbone", "resnet"), ("--seed", "-1")]],
    (["describe", "{imgs}", "--method", "sift", "--out", "{out}/d.h5"], "--method"),
    # demo
    *[(["demo", "--out", "{out}/demo", opt, val], opt) for opt, val in [
        ("--places", "5"), ("--seed", "-1"), ("--epochs", "0")]],
    # benchmark
    *[(["benchmark", "nordland64", "--data", "{imgs}", "--out", "{out}/b", opt, val], opt) for opt, val in [
        ("--pca-dims", "-5"), ("--train-range", "5:1"), ("--test-range", "x"), ("--seq-len", "0"), ("--top-k", "0"),
        ("--descriptor", "sift"), ("--epochs", "0"), ("--patch", "-1")]],
    # dataset
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "-3", "--out", "{out}/o"], "--radius"),
    (["dataset", "from-images", "{imgs}", "{imgs}", "--method", "pixels", "--frame-aligned", "--radius", "0",
      "--out", "{out}/o"], "--radius"),
    # global
    (["--threads", "0", "eval", "--dataset", "{ds}"], "--threads"),
    (["eval", "--dataset", "{ds}", "--threads", "-2"], "--threads"),
    (["eval", "--dataset", "{ds}", "--shortlist", "x"], "unrecognized arguments"),  # no abbreviations
    (["frobnicate"], "invalid choice"),
    ([], "required: COMMAND"),
]


@pytest.mark.parametrize("argv, pattern", BAD_OPTIONS, ids=[" ".join(a[0][:1] + a[0][-2:]) for a in BAD_OPTIONS])
def test_bad_option_values(base, tmp_path, capsys, argv, pattern):
    fill = {"ds": str(base / "ds"), "out": str(tmp_path), "imgs": str(base / "imgs"), "base": str(base)}
    run(capsys, [a.format(**fill) for a in argv], 2, pattern)
    assert list(tmp_path.iterdir()) == []  # nothing written


# ----------------------------------------------------------------------------- bad values found after parsing

LATE = [
    (["eval", "--dataset", "{ds}", "--method", "nope"], "unknown method 'nope'"),
    (["eval", "--dataset", "{ds}", "--method", "hvpr-nope"], "unknown HVPR shortlister"),
    (["eval", "--dataset", "{ds}", "--method", "hvpr-delta:raw+nope"], "re-ranker"),
    (["eval", "--dataset", "{ds}", "--method", "hvpr"], "needs an S_1 model"),
    (["eval", "--dataset", "{ds}", "--method", "s1"], "needs an S_1 model"),
    (["eval", "--dataset", "{ds}", "--method", "delta", "--seq-len", "1"], "need seq_len >= 2"),
    (["eval", "--dataset", "{ds}", "--method", ","], "no method"),
    (["eval", "--dataset", "{ds}", "--method", ""], "empty value"),
    (["eval", "--dataset", "{ds}", "--json", ""], "empty value"),
    (["eval", "--dataset", "{ds}", "--seq-len", "999"], "longer than the query traverse"),
    (["eval", "--dataset", "{ds}", "--radius", "1e-300"], "so Recall@K is undefined"),
    (["eval", "--dataset", "{ds}", "--split", "nope"], "has no split 'nope'"),
    (["eval", "--dataset", "{ds}", "--device", "tpu9"], "device"),
    (["eval", "--dataset", "{ds}", "--device", "cuda:7"], "cuda"),
    (["eval", "--dataset", "{base}/nowhere"], "dataset directory not found"),
    (["eval", "--dataset", "{base}/notes.txt"], "not a directory"),
    (["eval", "--dataset", "{ds}", "--model", "{base}/garbage.pt"], "cannot read checkpoint"),
    (["eval", "--dataset", "{ds}", "--model", "{base}/nowhere.pt"], "not found"),
    (["eval", "--dataset", "{ds}", "--model", "{base}"], "directory"),
    (["eval", "--dataset", "{ds}", "--per-query", "{out}/pq.xml"], "must end in .csv, .jsonl or .txt"),
    (["synth", ""], "empty value"),
    (["train", "--dataset", "{ds}", "--out", "{out}/r", "--w", "9"], "w must be"),
    (["train", "--dataset", "{ds}", "--out", "{out}/r", "--train-split", "nope"], "no split 'nope'"),
    (["train", "--dataset", "{ds}", "--out", "{out}/r", "--val-split", "nope"], "no split 'nope'"),
    (["train", "--dataset", "{ds}", "--out", "{out}/r", "--pos-radius", "50", "--neg-radius", "5"], "pos_radius"),
    (["train", "--dataset", "{ds}", "--out", "{out}/r", "--seq-len", "400"], "seq_len"),
    (["train", "--out", "{out}/r"], "no dataset"),
    (["train", "--resume", "{base}/nowhere"], "not found"),
    (["describe", "{base}/nowhere", "--method", "pixels", "--out", "{out}/d.h5"], "not found"),
    (["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.txt"], "must end in"),
    (["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.h5", "--resize", "0x5"], "size must be"),
    (["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.h5", "--resize", "60000x60000"], "1..8192"),
    (["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.h5", "--resize", "keep-aspect:0"], "keep-aspect"),
    (["describe", "{imgs}", "--method", "gem", "--out", "{out}/d.h5", "--layer", "99"], "layer"),
    (["describe", "{imgs}", "--method", "netvlad", "--out", "{out}/d.h5", "--checkpoint", "{base}/garbage.pt"],
     "cannot read NetVLAD checkpoint"),
    (["describe", "{base}/bombs", "--method", "pixels", "--out", "{out}/d.h5"], "is too large"),
    (["describe", "{imgs}", "--method", "pixels", "--out", "{out}/d.h5", "--crop-bottom", "999"], "crop-bottom"),
    (["dataset", "check", "{base}/nowhere"], "not found"),
    (["dataset", "from-csv", "--ref-csv", "{base}/latin1.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "not UTF-8"),
    (["dataset", "from-csv", "--ref-csv", "{base}/short_row.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "line 3"),
    (["dataset", "from-csv", "--ref-csv", "{base}/dup.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "lines 2 and 3"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/garbage.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "no NumPy header"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/garbage.h5", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "as HDF5"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/zeros.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "all zeros"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/nan.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "NaN"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/strings.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{out}/o"], "floating point"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4_16.npy", "--radius", "1", "--out", "{out}/o"], "dimension"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/empty.npy", "--ref-names",
      "{base}/empty.txt", "--query-csv", "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1",
      "--out", "{out}/o"], "names"),
    (["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
      "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--positives", "{base}/bad_positives.json",
      "--out", "{out}/o"], "expected a JSON list"),
    (["dataset", "from-seqnet", "--db", "{base}/text.db", "--ref-desc", "{base}/d4.npy", "--query-desc",
      "{base}/d4.npy", "--out", "{out}/o"], "MATLAB"),
    (["dataset", "from-seqnet", "--db", "{base}/empty.db", "--ref-desc", "{base}/d4.npy", "--query-desc",
      "{base}/d4.npy", "--out", "{out}/o"], "MATLAB"),
    (["dataset", "from-seqnet", "--ref-desc", "{base}/d4.npy", "--query-desc", "{base}/d4.npy", "--out",
      "{out}/o"], "without --db"),
    (["dataset", "from-images", "{imgs}", "{base}/nowhere", "--method", "pixels", "--frame-aligned", "--radius",
      "1", "--out", "{out}/o"], "not found"),
    (["dataset", "from-images", "{imgs}", "{imgs}", "--method", "pixels", "--frame-aligned", "--radius", "1",
      "--fit-on", "train", "--out", "{out}/o"], "--fit-on 'train' is not one of reference, both or a split name"),
    (["dataset", "from-images", "{imgs}", "{imgs}", "--method", "pixels", "--ref-csv", "{base}/ok.csv",
      "--radius", "1", "--out", "{out}/o"], "--ref-csv needs --query-csv"),
    (["benchmark", "nordland64", "--data", "{base}/nowhere", "--out", "{out}/b"], "is not the nordland64 data"),
]


@pytest.mark.parametrize("argv, pattern", LATE, ids=[f"{a[0][0]}-{i}" for i, a in enumerate(LATE)])
def test_bad_inputs_after_parsing(base, tmp_path, capsys, argv, pattern):
    fill = {"ds": str(base / "ds"), "out": str(tmp_path), "imgs": str(base / "imgs"), "base": str(base)}
    before = sorted(p.name for p in base.iterdir())
    run(capsys, [a.format(**fill) for a in argv], 2, pattern)
    assert sorted(p.name for p in base.iterdir()) == before  # no input file lost or added
    leftovers = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert leftovers == [], leftovers  # nothing half-written


# ----------------------------------------------------------------------------- never touch a user's file


def test_describe_keeps_files_beside_its_output(base, tmp_path, capsys):
    (tmp_path / "ref.netvlad.pth.tar").write_text("my model")
    (tmp_path / "ref.pca.npz").write_text("my pca")
    assert main(["-q", "describe", str(base / "imgs"), "--method", "pixels", "--out", str(tmp_path / "ref.npy")]) == 0
    assert (tmp_path / "ref.netvlad.pth.tar").read_text() == "my model"
    assert (tmp_path / "ref.pca.npz").read_text() == "my pca"


@pytest.mark.parametrize("argv", [
    ["synth", "{mine}", "--overwrite"],
    ["demo", "--out", "{root}", "--places", "150", "--epochs", "1"],
    ["dataset", "from-csv", "--ref-csv", "{base}/ok.csv", "--ref-desc", "{base}/d4.npy", "--query-csv",
     "{base}/ok.csv", "--query-desc", "{base}/d4.npy", "--radius", "1", "--out", "{mine}", "--overwrite"],
    ["dataset", "from-images", "{base}/imgs", "{base}/imgs", "--method", "pixels", "--frame-aligned", "--radius",
     "1", "--out", "{mine}", "--overwrite"],
    ["train", "--dataset", "{base}/ds", "--out", "{mine}", "--epochs", "1"],
])
def test_commands_never_replace_a_users_directory(base, tmp_path, capsys, argv):
    mine = tmp_path / ("train_seqnet" if "demo" in argv else "mine")
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    fill = {"mine": str(mine), "root": str(tmp_path), "base": str(base)}
    capsys.readouterr()
    rc = main([a.format(**fill) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert (mine / "thesis.tex").read_text() == "precious" and sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]


def test_resume_writes_only_to_the_resumed_run(base, tmp_path, capsys):
    assert main(["-q", "train", "--dataset", str(base / "ds"), "--out", str(tmp_path / "a"), "--epochs", "1",
                 "--seq-len", "3", "--w", "2"]) == 0
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "best.pt").write_text("another run's model")
    run(capsys, ["train", "--resume", str(tmp_path / "a"), "--out", str(tmp_path / "b"), "--epochs", "2"], 2,
        "continues the run in")
    assert (tmp_path / "b" / "best.pt").read_text() == "another run's model"


# ----------------------------------------------------------------------------- the environment fails: exit 1


@pytest.mark.parametrize("err, reason", [(errno.ENOSPC, "no space left on device"),
                                         (errno.EROFS, "read-only file system"),
                                         (errno.EACCES, "permission denied")])
def test_os_write_failures_exit_1(base, tmp_path, capsys, monkeypatch, err, reason):
    real = os.replace

    def failing(src, dst, *a, **k):
        if str(dst).endswith("results.json"):
            raise OSError(err, os.strerror(err), str(src))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", failing)
    line = run(capsys, ["eval", "--dataset", str(base / "ds"), "--method", "single", "--out", str(tmp_path / "o")],
               1, reason)
    assert str(tmp_path / "o" / "results.json") in line  # the user's path, not the temporary file
    assert not (tmp_path / "o").exists()  # the set appears whole or not at all
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]  # nor its temporary folder


def _hold_lock(path, ready, release):
    from seqnet.security.locks import locked

    with locked(path):
        ready.set()
        release.wait(30)


def test_second_writer_is_refused_exit_1(base, tmp_path, capsys):
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    proc = ctx.Process(target=_hold_lock, args=(tmp_path / "run", ready, release))
    proc.start()
    try:
        assert ready.wait(30)
        run(capsys, ["train", "--dataset", str(base / "ds"), "--out", str(tmp_path / "run"), "--epochs", "1"], 1,
            f"in use by another seqnet process (PID {proc.pid}")
        run(capsys, ["synth", str(tmp_path / "run")], 1, "in use by another seqnet process")
    finally:
        release.set()
        proc.join(30)


def test_out_of_memory_is_one_line(base, tmp_path, capsys, monkeypatch):
    import importlib

    ev = importlib.import_module("seqnet.eval.evaluate")  # the module (seqnet.eval.evaluate is also the function)

    def boom(*a, **k):
        raise MemoryError("could not allocate 4 TiB")

    monkeypatch.setattr(ev, "evaluate_split", boom)  # what seqnet eval calls
    run(capsys, ["eval", "--dataset", str(base / "ds")], 1, "out of memory")


# ----------------------------------------------------------------------------- numbers: valid but dangerous


def test_big_endian_and_huge_values_give_the_same_results(tmp_path, capsys):
    ds = make_synthetic(places=150, dim=8, seed=5)
    res = {}
    for kind, scale in (("plain", None), ("big-endian", None), ("huge", 1e19)):
        d = ds
        if kind == "big-endian":
            d = _with(ds, lambda x: x.astype(">f4"))
        if scale:
            d = _with(ds, lambda x, s=scale: x * np.float32(s))
        save_dataset(d, tmp_path / kind)
        assert main(["-q", "eval", "--dataset", str(tmp_path / kind), "--method", "single,raw+seqmatch,delta",
                     "--out", str(tmp_path / f"o-{kind}")]) == 0
        res[kind] = json.loads((tmp_path / f"o-{kind}" / "results.json").read_text())["methods"]
    for kind in ("big-endian", "huge"):
        for m in res["plain"]:
            assert res[kind][m]["recall@1"] == res["plain"][m]["recall@1"], (kind, m)


def _with(ds, fn):
    import dataclasses

    return dataclasses.replace(ds, reference=ds.reference.with_descriptors(fn(ds.reference.descriptors)),
                               query=ds.query.with_descriptors(fn(ds.query.descriptors)))


def test_nan_weights_are_refused(base, tmp_path, capsys):
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    model = SeqNet(8, 8, 5, 3)
    with torch.no_grad():
        model.conv.weight[0, 0, 0] = float("nan")
    save_checkpoint(tmp_path / "nan.pt", model)
    run(capsys, ["eval", "--dataset", str(base / "ds"), "--model", str(tmp_path / "nan.pt")], 2, "hold NaN or inf")


@pytest.mark.parametrize("flags, pattern", [('{"seqL": "abc"}', "seqL must be an integer"),
                                            ('{"seqL": 5, "w": [1]}', "w must be an integer"),
                                            ("[1, 2]", "JSON object"), ("{broken", "not valid JSON")])
def test_original_checkpoint_with_bad_flags(base, tmp_path, capsys, flags, pattern):
    ckpt = {"state_dict": {"pool.0.conv.weight": torch.zeros(8, 8, 3) + 0.1, "pool.0.conv.bias": torch.zeros(8)}}
    torch.save(ckpt, tmp_path / "model_best.pth.tar")
    (tmp_path / "flags.json").write_text(flags)
    run(capsys, ["eval", "--dataset", str(base / "ds"), "--shortlist-model", str(tmp_path / "model_best.pth.tar")],
        2, pattern)


def test_list_state_dict_is_refused(base, tmp_path, capsys):
    torch.save({"state_dict": [1, 2, 3]}, tmp_path / "odd.pt")
    run(capsys, ["eval", "--dataset", str(base / "ds"), "--model", str(tmp_path / "odd.pt")], 2,
        "'state_dict' must map parameter names to tensors")


# ----------------------------------------------------------------------------- the Python API


def test_api_errors_are_seqnet_errors():
    from seqnet import Dataset, EvalConfig, Traverse, evaluate, seqmatch
    from seqnet.core.errors import SeqnetError
    from seqnet.train import TrainConfig, train

    ds = make_synthetic(places=150, dim=8)
    t = Traverse(np.ones((3, 2), np.float32), np.arange(3.0))
    cases = [
        lambda: Dataset(t, t, radius="5"),
        lambda: Dataset(t, "query", radius=1.0),
        lambda: evaluate(ds, ["single"]),
        lambda: evaluate(ds.split("test"), EvalConfig(methods=("single",)), models=[1]),
        lambda: evaluate(ds.split("test"), EvalConfig(methods=("single",)), models={"s2": None}),
        lambda: EvalConfig(methods="single"),
        lambda: EvalConfig.from_dict({"method": ["single"]}),
        lambda: TrainConfig(lr=-1),
        lambda: train(ds, {"epochs": 1}, "/tmp/never"),
        lambda: seqmatch(np.full((5, 3), np.nan), np.ones((5, 3)), 2),
        lambda: seqmatch(np.full((5, 3), 1e30, np.float32), np.full((5, 3), -1e30, np.float32), 2),
        lambda: seqmatch(np.ones((5, 3)), np.ones((5, 4)), 2),
        lambda: seqmatch(np.ones((5, 3)), np.ones((5, 3)), 0),
    ]
    for i, fn in enumerate(cases):
        with pytest.raises(SeqnetError):
            fn()
            pytest.fail(f"case {i} did not raise")
    assert not Path("/tmp/never").exists()
