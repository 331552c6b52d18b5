"""The benchmark's choices on val: the descriptor proxy (never reads a test image), explicit flags win."""

from __future__ import annotations

import json
import shutil

import pytest
from conftest import shared_data

from seqnet.core.errors import ConfigError
from seqnet.pipelines.descriptor_choice import runnable
from seqnet.pipelines.nordland64 import Nordland64Config
from seqnet.pipelines.nordland64.config import SELECTABLE
from seqnet.pipelines.nordland64.select import candidate_config, descriptor_on_val


def conf_of(*flags):
    from seqnet.cli import build_parser
    from seqnet.cli.benchmark_cmd import nordland64_config

    argv = ["benchmark", "nordland64", "--data", "D", "--out", "O", *flags]
    return nordland64_config(build_parser(argv).parse_args(argv))


def test_explicit_flags_win():
    assert conf_of().select == SELECTABLE  # nothing given: everything chosen on val
    c = conf_of("--top-k", "7", "--fuse-weight", "0.5", "--descriptor", "netvlad")
    assert c.select == ("fuse_top_k",) and (c.top_k, c.fuse_weight, c.describe.method) == (7, 0.5, "netvlad")
    assert "descriptor" not in conf_of("--patch", "8").select  # --patch means pixels
    assert conf_of("--fuse-top-k", "100").select == ("descriptor", "top_k", "fuse_weight")
    assert conf_of("--cnn-size", "64x32").cnn_size == (64, 32)  # without --descriptor: the CNN candidates'
    assert candidate_config(conf_of("--cnn-size", "64x32"), "gem").size == (64, 32)
    assert conf_of("--descriptors", "pixels,gmp").descriptors == ("pixels", "gmp")
    with pytest.raises(ConfigError, match="descriptor"):
        conf_of("--descriptors", "pixels,sift")
    nv = candidate_config(Nordland64Config(), "netvlad")  # what --descriptor netvlad --cnn-size 128x64 gives
    assert nv == conf_of("--descriptor", "netvlad", "--cnn-size", "128x64").describe
    assert runnable(candidate_config(Nordland64Config(), "pixels")) is None


def nordland_copy(tmp_path, n=60, poison=range(0)):
    """The first ``n`` nordland64 places (real frames); those of ``poison`` replaced by unreadable files."""
    src, data = shared_data("nordland64"), tmp_path / "n64"
    names = [f"images-{i:05d}.png" for i in range(0, 30000, 10)]
    names = [x for x in names if (src / "summer" / x).is_file() and (src / "winter" / x).is_file()][:n]
    for season in ("summer", "winter"):
        (data / season).mkdir(parents=True)
        for i, x in enumerate(names):
            if i in poison:
                (data / season / x).write_bytes(b"not an image")
            else:
                shutil.copy(src / season / x, data / season / x)
    (data / "nordland_clean_imageNames.txt").write_text("".join(f"{x}\n" for x in names))
    return data


def test_the_descriptor_proxy_never_reads_a_test_image(tmp_path, monkeypatch):
    """Test images replaced by unreadable files: the same scores, the same choice (a candidate with a PCA fitted
    on train images stands in for the CNN ones: the same path, without a CNN's seconds)."""
    from seqnet.describe import DescribeConfig
    from seqnet.pipelines.nordland64 import select

    fitted = DescribeConfig(method="pixels", patch=8, size="native", dim=8)
    monkeypatch.setattr(select, "candidate_config", lambda c, n: fitted if n == "gmp" else candidate_config(c, n))
    conf = Nordland64Config(train_range=(0, 20), val_range=(22, 40), test_range=(42, 60), device="cpu",
                            descriptors=("pixels", "gmp"))
    clean = nordland_copy(tmp_path / "a")
    poisoned = nordland_copy(tmp_path / "b", poison=range(42, 60))
    picked, record = descriptor_on_val(conf, clean)
    again, record2 = descriptor_on_val(conf, poisoned)
    strip = {n: {k: v for k, v in s.items() if k != "seconds"} for n, s in record["scores"].items()}
    assert strip == {n: {k: v for k, v in s.items() if k != "seconds"} for n, s in record2["scores"].items()}
    assert picked.describe == again.describe and record["chosen"] in ("pixels", "gmp")
    assert picked.describe == select.candidate_config(conf, record["chosen"]) and "chosen on val" in record["reason"]
    best = max(record["scores"].values(), key=lambda s: s["raw+seqmatch"])["raw+seqmatch"]
    assert record["scores"][record["chosen"]]["raw+seqmatch"] == best
    json.dumps(record)  # it goes into results.json
    same, none = descriptor_on_val(conf.replace(select=("top_k",)), poisoned)
    assert none is None and same.describe == conf.describe  # not asked: nothing described


def test_the_descriptor_choice_is_cached_whole(tmp_path, monkeypatch):
    """With the benchmark's folder the choice is a cache unit: the second run reuses it without describing; another
    val range or a changed record file chooses again; a user's file in its place is refused, never replaced."""
    from seqnet.core.errors import OutputError
    from seqnet.pipelines import descriptor_choice
    from seqnet.pipelines.nordland64 import select

    conf = Nordland64Config(train_range=(0, 20), val_range=(22, 40), test_range=(42, 60), device="cpu",
                            descriptors=("pixels", "gmp"))
    monkeypatch.setattr(descriptor_choice, "runnable", lambda d: None if d.method == "pixels" else "not installed")
    data, out = nordland_copy(tmp_path), tmp_path / "out"
    out.mkdir()
    calls = []
    real = select.proxy_scores
    monkeypatch.setattr(select, "proxy_scores", lambda *a: (calls.append(a[-1].method), real(*a))[1])
    first, rec = descriptor_on_val(conf, data, out)
    assert calls == ["pixels"] and "cached" not in rec and (out / "descriptor_choice.json").is_file()
    again, rec2 = descriptor_on_val(conf, data, out)
    assert calls == ["pixels"] and rec2["cached"] is True and again.describe == first.describe
    assert {k: v for k, v in rec2.items() if k != "cached"} == {**rec, "reason": rec2["reason"]}
    assert rec2["reason"] == rec["reason"] + " (an earlier run's choice in this folder, reused)"
    descriptor_on_val(conf.replace(val_range=(22, 38)), data, out)  # another val range: chosen again
    assert calls == ["pixels", "pixels"]
    (out / "descriptor_choice.json").write_text('{"chosen": "gmp"}')  # tampered: not reused, chosen again
    _, rec3 = descriptor_on_val(conf.replace(val_range=(22, 38)), data, out)
    assert calls == ["pixels"] * 3 and rec3["chosen"] == "pixels" and "cached" not in rec3
    other = tmp_path / "other"
    other.mkdir()
    (other / "descriptor_choice.json").write_text("mine")
    with pytest.raises(OutputError):
        descriptor_on_val(conf, data, other)
    assert (other / "descriptor_choice.json").read_text() == "mine"


def test_the_cached_choice_ignores_places_after_every_range(tmp_path, monkeypatch):
    """The places after the last range are never read: removing one keeps the cached choice; a val place changed
    chooses again."""
    from seqnet.pipelines import descriptor_choice
    from seqnet.pipelines.nordland64 import select

    conf = Nordland64Config(train_range=(0, 20), val_range=(22, 40), test_range=(42, 60), device="cpu",
                            descriptors=("pixels", "gmp"))
    monkeypatch.setattr(descriptor_choice, "runnable", lambda d: None if d.method == "pixels" else "not installed")
    data, out = nordland_copy(tmp_path, n=66), tmp_path / "out"
    out.mkdir()
    calls = []
    real = select.proxy_scores
    monkeypatch.setattr(select, "proxy_scores", lambda *a: (calls.append(a[-1].method), real(*a))[1])
    descriptor_on_val(conf, data, out)
    last = sorted((data / "summer").iterdir())[-1].name
    for season in ("summer", "winter"):
        (data / season / last).unlink()  # place 65: after every range
    _, rec = descriptor_on_val(conf, data, out)
    assert calls == ["pixels"] and rec["cached"] is True
    val_place = sorted((data / "summer").iterdir())[30].name
    for season in ("summer", "winter"):
        (data / season / val_place).unlink()  # a val place: the places in use changed
    _, rec = descriptor_on_val(conf, data, out)
    assert calls == ["pixels", "pixels"] and "cached" not in rec
