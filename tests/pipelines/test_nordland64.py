"""The Nordland64 benchmark: PCA folding, place listing and a tiny end-to-end run on the shared data."""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest
import torch
from conftest import shared_data
from report.test_report_html import assert_self_contained

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError, DatasetError
from seqnet.data.traverse import Dataset, Traverse
from seqnet.describe.pca import fit_pca
from seqnet.pipelines.nordland64 import Nordland64Config, describe_flipped, fold_pca, list_places, training_dataset
from seqnet.pipelines.nordland64.models import fit_train_pca, train_key
from seqnet.security.text import shown
from seqnet.sequence.model import SeqNet


def test_fold_pca_is_exact(rng):
    x = rng.standard_normal((40, 7, 32)).astype(np.float32)
    pca = fit_pca(x.reshape(-1, 32), 12, whiten=True, l2=False)
    torch.manual_seed(0)
    model = SeqNet(12, 6, seq_len=7, w=3)
    projected = torch.from_numpy(pca.transform(x.reshape(-1, 32), l2=False).reshape(40, 7, 12))
    folded = fold_pca(model, pca)
    assert folded.in_dims == 32 and folded.config()["w"] == 3
    with torch.no_grad():
        torch.testing.assert_close(folded(torch.from_numpy(x)), model(projected), atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize(("pca_dims", "kept"), [(4, 4), (11, 11), (12, 11), (64, 11)])
def test_train_pca_is_capped_at_one_below_the_training_images(rng, pca_dims, kept):
    """6 + 6 train images span at most 11 axes once centred: more dims are capped, not refused."""
    d = rng.standard_normal((10, 16)).astype(np.float32)
    pos = np.arange(10) / 1.0
    ds = Dataset(Traverse(d, pos), Traverse(d + 0.1, pos), radius=1.0, position_unit="frames",
                 splits={"train": {"reference": (0, 6), "query": (0, 6)}})
    pca = fit_train_pca(ds, Nordland64Config(pca_dims=pca_dims))
    assert pca.transform(d, l2=False).shape == (10, kept)


def test_training_dataset_symmetric(rng):
    d_r, d_q = rng.random((50, 4), dtype=np.float32), rng.random((50, 4), dtype=np.float32)
    pos = np.arange(50) / 1.0
    ds = Dataset(Traverse(d_r, pos), Traverse(d_q, pos), radius=1.0, position_unit="frames",
                 splits={"train": {"reference": (0, 30), "query": (0, 30)},
                         "val": {"reference": (35, 45), "query": (35, 45)}},
                 extra={"pos_radius": 1.0, "neg_radius": 4.0})
    t = training_dataset(ds, None, symmetric=True)
    assert t.splits["train"]["query"] == (0, 60) and t.splits["val"]["query"] == (60, 70)
    np.testing.assert_array_equal(t.query.descriptors[30:60], d_r[:30])  # summer queries -> winter refs
    np.testing.assert_array_equal(t.reference.descriptors[30:60], d_q[:30])
    np.testing.assert_array_equal(t.query.descriptors[60:], d_q[35:45])  # val stays winter -> summer
    assert t.reference.positions[30, 0] > 100 and t.query.seq_bounds[59].tolist() == [30, 60]
    assert training_dataset(ds, None, symmetric=False).splits["train"]["query"] == (0, 30)
    flipped = rng.random((2, 30, 4), dtype=np.float32)
    t = training_dataset(ds, None, symmetric=True, flipped=flipped)
    assert t.splits["train"]["query"] == (0, 120) and t.splits["val"]["query"] == (120, 130)
    np.testing.assert_array_equal(t.reference.descriptors[30:60], flipped[0])  # mirrored summer -> winter
    np.testing.assert_array_equal(t.query.descriptors[90:120], flipped[0])  # and winter -> summer
    gaps = np.diff(t.query.positions[:120, 0])
    assert np.all(np.abs(gaps[[29, 59, 89]]) > 100)  # sequences never within a radius of each other


def test_flipped_pixels_are_mirrored_descriptors():
    from seqnet.describe import DescribeConfig, make_describer

    data = shared_data("nordland64")
    paths = [data / "summer" / f"images-{i:05d}.png" for i in (210, 220, 230)]
    d = make_describer(DescribeConfig(), paths)
    plain, _ = d.describe(paths)
    perm = np.arange(plain.shape[1]).reshape(32, 64)[:, ::-1].ravel()
    np.testing.assert_allclose(describe_flipped(d, paths), plain[:, perm], atol=1e-6)


def test_config_rejects_unknown_keys_and_bad_values():
    with pytest.raises(ConfigError, match="unknown Nordland64Config key 'epochz'"):
        Nordland64Config.from_dict({"epochz": 3})
    assert Nordland64Config().test_range == (1940, 2761)
    with pytest.raises(ConfigError, match="pca_dims"):
        Nordland64Config(pca_dims=-5)
    with pytest.raises(ConfigError, match="w=5.*evaluated with L=3, shorter than its convolution width"):
        Nordland64Config(seq_len=3)
    assert Nordland64Config(train=Nordland64Config().train.replace(seq_len=10), seq_len=5).seq_len == 5
    conf = Nordland64Config.from_dict(Nordland64Config().to_dict())
    assert conf == Nordland64Config()


def test_list_places_and_bad_data(tmp_path):
    data = shared_data("nordland64")
    names, pos = list_places(data)
    assert len(names) == 2761 and names[0] == "images-00210.png" and pos[0] == 21.0
    assert np.all(np.diff(pos) > 0)
    with pytest.raises(DatasetError, match="summer is missing"):
        list_places(tmp_path)


def test_tiny_benchmark_end_to_end(tmp_path, capsys):
    data = shared_data("nordland64")
    out = tmp_path / "b"
    args = ["benchmark", "nordland64", "--data", str(data), "--out", str(out), "--train-range", "0:120",
            "--val-range", "130:170", "--test-range", "180:260", "--epochs", "1", "--threads", "2", "--pca-dims", "64",
            "--descriptors", "pixels,gmp"]
    with open(tmp_path / "log", "w") as log:  # the log reads well in a file: no bars, a few lines
        with contextlib.redirect_stderr(log):
            assert cli_main(args) == 0
    text = (tmp_path / "log").read_text()
    assert "\r" not in text and len(text.splitlines()) < 30, text
    res = json.loads((out / "results.json").read_text())
    methods = res["methods"]
    assert list(methods) == ["single", "s1", "smoothing", "delta", "seqnet", "raw+seqmatch", "s1+seqmatch",
                             "delta+seqmatch", "hvpr", "hvpr-single", "hvpr-delta", "hvpr-fused"]
    assert all(0.0 <= m["recall@1"] <= m["recall@20"] <= 1.0 for m in methods.values())
    assert methods["single"]["queries"] == 76  # places 180..259 with a full centred L=5 window and a match
    assert res["config"]["benchmark"]["test_range"] == [180, 260] and "total" in res["config"]["timings_s"]
    assert res["methods"]["hvpr-single"]["method"]["rerank"] == "s1+seqmatch"
    sel, bench = res["selection"], res["config"]["benchmark"]  # chosen on val, and said
    assert sel["descriptor"]["chosen"] == bench["describe"]["method"] and set(sel["descriptor"]["scores"]) == \
        {"pixels", "gmp"}
    assert [c["method"] for c in sel["hvpr"]] == ["hvpr", "hvpr-single", "hvpr-delta", "hvpr-fused"]  # each its own
    for c in sel["hvpr"]:
        k = c["settings"].get("top_k", c["settings"].get("fuse_top_k"))
        assert bench["method_top_k"][c["method"]] == k == methods[c["method"]]["method"]["top_k"]
    assert bench["method_fuse_weight"]["hvpr-fused"] == sel["hvpr"][3]["settings"]["fuse_weight"] == \
        methods["hvpr-fused"]["method"]["fuse_weight"]
    assert "Chosen on val (never on test): descriptor" in (out / "results.md").read_text()
    md = (out / "results.md").read_text()
    dim = np.load(out / "dataset" / "query" / "descriptors.npy", mmap_mode="r").shape[1]  # the headline: as described
    assert f"; descriptor `{sel['descriptor']['chosen']}` (D={dim})." in md and "by the val proxy's model-free" in md
    assert "radius 1 (frame steps)" in md  # nordland64's ground truth: the radius
    for n in res["learned_below_baseline"]:  # each flagged row marked as in the terminal table, its note below
        row = next(line for line in md.splitlines() if line.startswith(f"| {n['learned']} |"))
        assert row.endswith(f"| learned, below model-free {n['baseline']} |")
        assert f"{n['learned']} (R@1 {n['learned_r1']:.3f}) is below the model-free {n['baseline']}" in md
        assert f"| learned, below model-free {n['baseline']} |" not in _row(md, n["baseline"])
    assert ("| note |" in md) == bool(res["learned_below_baseline"])
    assert (out / "recall_at_k.png").stat().st_size > 1000 and "| hvpr |" in (out / "results.md").read_text()
    assert (out / "models" / "seqnet.pt").is_file() and (out / "dataset" / "dataset.json").is_file()
    assert_self_contained(out / "report.html")  # the HTML report, one file
    assert (out / "report.html").read_text().count('class="ex ') == 12  # the gallery, with the images
    # a second run reuses the cached descriptors and models
    assert cli_main(args) == 0
    again = json.loads((out / "results.json").read_text())["methods"]
    assert {m: r["recall@5"] for m, r in again.items()} == {m: r["recall@5"] for m, r in methods.items()}
    printed = capsys.readouterr().out
    assert "nordland64 test 180:260" in printed and "chosen on val places 130:170" in printed


def test_bad_range_is_reported(tmp_path, capsys):
    data = shared_data("nordland64")
    rc = cli_main(["benchmark", "nordland64", "--data", str(data), "--out", str(tmp_path / "b"),
                   "--test-range", "2000:9000"])
    assert rc == 2 and "--test-range 2000:9000 is outside 0:2761" in capsys.readouterr().err


def test_learning_flags_reach_the_training_settings():
    from seqnet.cli import build_parser
    from seqnet.cli.benchmark_cmd import nordland64_config

    def conf(*flags):
        argv = ["benchmark", "nordland64", "--data", "D", "--out", "O", *flags]
        return nordland64_config(build_parser(argv).parse_args(argv))

    c = conf("--s1-loss", "seqmatch", "--s1-margin", "1.5", "--speed-augment", "0.5:2", "--seq-len", "6", "--w", "3")
    assert (c.train_s1.loss, c.train_s1.margin, c.train_s1.match_len) == ("seqmatch", 1.5, 6)
    assert c.train.speed_augment == (0.5, 2.0) and c.train_s1.speed_augment is None and c.train.seq_len == 6
    assert conf("--speed-augment", "1:1").train.speed_augment is None  # 1:1 turns it off
    old = conf("--fuse-weight", "0.5", "--fuse-top-k", "100").eval_config()
    assert (old.fuse_weight, old.fuse_top_k, conf().fuse_weight, conf().fuse_top_k) == (0.5, 100, 0.25, 200)
    assert conf().train == Nordland64Config().train and conf().train_s1 == Nordland64Config().train_s1
    assert train_key(c) != train_key(Nordland64Config())  # other settings, other cached models
    assert conf().eval_config().recall_denominator == "positives"
    every = conf("--recall-denominator", "all")
    assert every.eval_config().recall_denominator == "all" and train_key(every) == train_key(conf())


def test_cnn_size_sets_a_cnn_descriptors_input_and_is_refused_for_pixels(tmp_path, capsys):
    from seqnet.cli import build_parser
    from seqnet.cli.benchmark_cmd import nordland64_config

    def conf(*flags):
        argv = ["benchmark", "nordland64", "--data", "D", "--out", "O", *flags]
        return nordland64_config(build_parser(argv).parse_args(argv))

    nv = conf("--descriptor", "netvlad", "--cnn-size", "128x64")
    assert (nv.describe.method, nv.describe.size) == ("netvlad", (128, 64))
    assert conf("--descriptor", "netvlad").describe.size == "auto"  # the describer's own
    assert train_key(nv) != train_key(conf("--descriptor", "netvlad"))  # other descriptors, other models
    rc = cli_main(["benchmark", "nordland64", "--data", "D", "--out", str(tmp_path / "o"), "--descriptor", "pixels",
                   "--cnn-size", "128x64"])
    assert rc == 2 and "hint: --descriptor netvlad" in capsys.readouterr().err
    rc = cli_main(["benchmark", "nordland64", "--data", "D", "--out", str(tmp_path / "o"), "--descriptor", "gmp",
                   "--cnn-size", "12x"])
    assert rc == 2 and "got '12x'" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["cover.png", "\x1b[Kcover\x07.png"])
def test_an_image_name_without_a_frame_number_is_one_line(tmp_path, capsys, bad):
    """The frame number is the last run of digits of a name; a name without one is a one-line error naming it
    (escaped: a hostile name cannot drive the terminal) and the pattern, exit 2 (it was a traceback)."""
    data = tmp_path / "n64"
    for season in ("summer", "winter"):
        (data / season).mkdir(parents=True)
        for name in ("images-00010.png", bad):
            (data / season / name).write_bytes(b"")
    (data / "nordland_clean_imageNames.txt").write_text(f"images-00010.png\n{bad}\n")
    rc = cli_main(["benchmark", "nordland64", "--data", str(data), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "\x1b" not in err, err
    assert "has no frame number (expected names like images-00210.png" in err
    assert f"'{shown(bad)}'" in err and "nordland_clean_imageNames.txt" in err
    assert not (tmp_path / "o" / "dataset").exists()


def test_the_benchmark_replaces_only_what_it_wrote(tmp_path, capsys, synth_dataset):
    """D6/D8: a user's seqnet dataset where the cache goes, or a file of theirs in place of an output, is refused
    before any work (the dataset: unless --overwrite; the file: even then)."""
    from seqnet.data.io import save_dataset

    data, out = shared_data("nordland64"), tmp_path / "b"
    mine = save_dataset(synth_dataset, out / "dataset")
    argv = ["benchmark", "nordland64", "--data", str(data), "--out", str(out), "--train-range", "0:120",
            "--val-range", "130:170", "--test-range", "180:260"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert "dataset was not made by this cache" in err and "--overwrite" in err
    assert json.loads((mine / "dataset.json").read_text())["name"] == synth_dataset.name
    (out / "report.html").write_text("<p>my own report</p>")
    for extra in ([], ["--overwrite"]):
        assert cli_main([*argv, *extra]) == 2
        assert "report.html was not written by seqnet" in capsys.readouterr().err
    assert (out / "report.html").read_text() == "<p>my own report</p>"
    assert json.loads((mine / "dataset.json").read_text())["name"] == synth_dataset.name


def _row(md: str, name: str) -> str:
    return next(line for line in md.splitlines() if line.startswith(f"| {name} |"))
