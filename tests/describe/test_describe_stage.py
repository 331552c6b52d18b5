"""Tests of the describe stage's file output: resuming, partial files, fitted-state ownership and the CLI."""

from __future__ import annotations

import json
import logging

import h5py
import numpy as np
import pytest
import torch
from describe.test_netvlad import make_checkpoint
from PIL import Image

import seqnet.describe.describer as describer_mod
from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.data.io import load_descriptors
from seqnet.describe import DescribeConfig, describe_folder, main


def describe(*args):
    """``seqnet describe ARGS`` (on CPU); the exit code."""
    return cli_main(["describe", *map(str, args), "--device", "cpu"])


def h5_contents(path):
    with h5py.File(path) as h:
        return h["descriptors"][()], [n.decode() for n in h["names"][()]], json.loads(h.attrs["config"])


@pytest.mark.parametrize("suffix", [".h5", ".npy"])
def test_output_readable_by_traverse_loader(folder, tmp_path, suffix, caplog):
    out = tmp_path / "trav" / f"descriptors{suffix}"
    with caplog.at_level(logging.INFO, logger="seqnet"):
        desc, names = describe_folder(folder, DescribeConfig(), out=out)
    summary = [r.getMessage() for r in caplog.records if "images/s" in r.getMessage()]
    assert len(summary) == 1 and summary[0].startswith("described 10 images of") and str(out) in summary[0]
    loaded, h5_names = load_descriptors(out.parent)
    np.testing.assert_array_equal(loaded, desc)
    got = h5_names if suffix == ".h5" else (out.parent / "names.txt").read_text().splitlines()
    assert got == names
    assert not list(out.parent.glob(".*partial*"))
    with pytest.raises(ConfigError, match="already exists"):
        describe_folder(folder, DescribeConfig(), out=out)


def test_main_returns_output_and_records_resolved_size(folder, tmp_path):
    out = main(DescribeConfig(method="gmp", size="native", layer=10, device="cpu"), folder, tmp_path / "g.h5")
    assert out == tmp_path / "g.h5"
    desc, _, config = h5_contents(out)
    assert config["size"] == "native" and config["method"] == "gmp" and desc.shape == (10, 112)
    (tmp_path / "one.txt").write_text("imgs/f1.png\n")  # 640x320 is slow on a CPU: one image
    assert main(DescribeConfig(method="gmp", layer=10, device="cpu"), tmp_path / "one.txt", tmp_path / "b.h5") == (
        tmp_path / "b.h5")
    desc, names, config = h5_contents(tmp_path / "b.h5")
    assert config["size"] == [640, 320] and names == ["imgs/f1.png"] and desc.shape == (1, 112)  # "auto" resolved


def test_cli_resize_native_is_honoured_by_cnn_methods(folder, tmp_path):
    assert describe(folder, "--method", "gmp", "--layer", "10", "--resize", "native", "--out", tmp_path / "n.h5") == 0
    assert describe(folder, "--method", "gmp", "--layer", "10", "--resize", "32x16", "--out", tmp_path / "r.h5") == 0
    native, _, config = h5_contents(tmp_path / "n.h5")
    assert config["size"] == "native"
    np.testing.assert_allclose(native, h5_contents(tmp_path / "r.h5")[0], atol=1e-6)  # 32x16 is their native size


def test_resume_skips_finished_images(folder, tmp_path, monkeypatch):
    out = tmp_path / "out.h5"
    conf = DescribeConfig(dim=4, batch_size=3)
    expected, _ = describe_folder(folder, conf)
    real_load = describer_mod.load_images
    loaded: list[str] = []

    def counting_load(paths, **k):
        loaded.extend(p.name for p in paths)
        if len(loaded) > 10 + 6:  # PCA fit (10 images) + 2 batches, then "crash"
            raise KeyboardInterrupt
        return real_load(paths, **k)

    monkeypatch.setattr(describer_mod, "load_images", counting_load)
    with pytest.raises(KeyboardInterrupt):
        describe_folder(folder, conf, out=out)
    partial = tmp_path / ".out.h5.seqnet-partial.h5"
    assert not out.exists() and partial.exists() and (tmp_path / "out.pca.npz").exists()
    with h5py.File(tmp_path / ".out.h5.seqnet-partial.h5") as h:
        assert h["status"][()].tolist() == [1] * 6 + [0] * 4
    loaded.clear()
    monkeypatch.setattr(describer_mod, "load_images", lambda paths, **k: (loaded.extend(p.name for p in paths),
                                                                           real_load(paths, **k))[1])
    desc, names = describe_folder(folder, conf, out=out)
    assert loaded == [f"f{i}.png" for i in range(6, 10)]  # PCA reused, finished images skipped
    np.testing.assert_allclose(desc, expected, atol=1e-6)
    assert names == [f"f{i}.png" for i in range(10)]


def test_partial_with_other_settings_starts_again(folder, tmp_path, caplog):
    (folder / "f9.png").unlink()
    Image.fromarray(np.zeros((20, 32, 3), np.uint8)).save(folder / "f9.png")  # discovered after 9 images
    out = tmp_path / "out.h5"
    assert describe(folder, "--method", "pixels", "--batch-size", "3", "--out", out) == 2
    partial = tmp_path / ".out.h5.seqnet-partial.h5"
    with h5py.File(partial) as h:
        assert h["status"][()].tolist() == [1] * 9 + [0]  # progress is kept for a resume
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert describe(folder, "--method", "pixels", "--resize", "32x16", "--out", out) == 0
    msg = " ".join(r.getMessage() for r in caplog.records)
    assert "other settings (size: native -> [32, 16]); discarding its 9 finished images" in msg
    assert out.exists() and not partial.exists()


@pytest.mark.parametrize("bad", [["--crop-bottom", "16"], []])
def test_failed_run_without_progress_leaves_no_partial(folder, tmp_path, bad, capsys):
    if not bad:
        (folder / "f0.png").write_bytes(b"broken")
    out = tmp_path / "out.npy"
    assert describe(folder, "--method", "pixels", *bad, "--out", out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("crop-bottom 16" in err[0] or "f0.png" in err[0]), err
    assert not list(tmp_path.glob(".*partial*"))
    fixed = ["--skip-corrupted"] if not bad else []
    assert describe(folder, "--method", "pixels", *fixed, "--out", out) == 0


# ----------------------------------------------------------------------------- fitted-state ownership


def test_user_files_beside_the_output_survive(folder, tmp_path, capsys):
    model, pca = tmp_path / "ref.netvlad.pth.tar", tmp_path / "ref.pca.npz"
    model.write_text("my model\n")
    pca.write_text("my pca\n")
    assert describe(folder, "--method", "pixels", "--out", tmp_path / "ref.npy") == 0
    assert "error" not in capsys.readouterr().err
    assert describe(folder, "--method", "pixels", "--dim", "3", "--out", tmp_path / "ref.h5") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ref.pca.npz exists and was not written for ref.h5" in err[0] and "hint" in err[0]
    assert model.read_text() == "my model\n" and pca.read_text() == "my pca\n"
    assert not list(tmp_path.glob(".*partial*"))


def test_fitted_netvlad_reused_as_checkpoint(folder, tmp_path, capsys):
    tiny = ["--method", "netvlad", "--resize", "64x32", "--batch-size", "2"]
    assert describe(folder, *tiny, "--clusters", "4", "--out", tmp_path / "nv.h5") == 0
    ckpt = tmp_path / "nv.netvlad.pth.tar"
    before = ckpt.read_bytes()
    assert describe(folder, *tiny, "--out", tmp_path / "nv.npy", "--checkpoint", ckpt) == 0
    assert ckpt.read_bytes() == before
    np.testing.assert_allclose(np.load(tmp_path / "nv.npy"), h5_contents(tmp_path / "nv.h5")[0], atol=1e-5)
    capsys.readouterr()
    # fitting for nv.npy would replace nv.h5's clusters: refused, file untouched
    assert describe(folder, *tiny, "--clusters", "4", "--out", tmp_path / "nv.npy", "--overwrite") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nv.netvlad.pth.tar exists and was not written for nv.npy" in err[0]
    assert ckpt.read_bytes() == before


def test_overwrite_refits_own_state(folder, tmp_path, caplog):
    out = tmp_path / "p.h5"
    assert describe(folder, "--method", "pixels", "--dim", "3", "--fit-on", "5", "--out", out) == 0
    first = h5_contents(out)[0]
    with caplog.at_level(logging.INFO, logger="seqnet"):
        assert describe(folder, "--method", "pixels", "--dim", "3", "--out", out, "--overwrite") == 0
    assert "removing" in caplog.text and "fitting PCA 512 -> 3 on 10 images" in caplog.text
    assert not np.allclose(first, h5_contents(out)[0])


def test_cli_netvlad_checkpoint_and_errors(folder, tmp_path, capsys):
    ckpt = tmp_path / "pitts_WPCA8.pth.tar"
    make_checkpoint(ckpt)
    out = tmp_path / "nv.h5"
    assert describe(folder, "--method", "netvlad", "--checkpoint", ckpt, "--resize", "32x32", "--out", out) == 0
    desc, names, _ = h5_contents(out)
    assert desc.shape == (10, 8) and names[0] == "f0.png"
    assert describe(folder, "--method", "gmp", "--checkpoint", ckpt, "--resize", "32x32", "--out",
                    tmp_path / "g.npy") == 0
    assert np.load(tmp_path / "g.npy").shape == (10, 16)
    bad = tmp_path / "bad.pth.tar"
    torch.save({"state_dict": {"pool.conv.weight": torch.zeros(2, 3, 1, 1)}}, bad)
    capsys.readouterr()
    for args, what in ((["--method", "netvlad", "--checkpoint", bad], "bad.pth.tar"),
                       (["--method", "pixels", "--resize", "0x3"], "size must be"),
                       (["--method", "gem", "--backbone", "vgg16"], "ships no weights"),
                       (["--method", "gem", "--layer", "99"], "layer 99")):
        assert describe(folder, *args, "--out", tmp_path / "x.h5") == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and what in err[0], err


def test_no_readable_image_leaves_no_partial(folder, tmp_path, capsys):
    for f in folder.iterdir():
        f.write_bytes(b"broken")
    assert describe(folder, "--method", "pixels", "--skip-corrupted", "--out", tmp_path / "o.h5") == 2
    assert "none of the 10 images could be read" in capsys.readouterr().err
    assert not list(tmp_path.glob(".*partial*")) and not (tmp_path / "o.h5").exists()


def test_partial_whose_fitted_state_is_gone_starts_again(folder, tmp_path, monkeypatch, caplog):
    out, conf = tmp_path / "o.h5", DescribeConfig(dim=3, batch_size=5)
    real_load = describer_mod.load_images
    calls = []

    def crash_on_second_batch(paths, **k):
        calls.append(len(paths))
        if len(calls) == 4:  # PCA fit (2 batches), 1 batch described, then "crash"
            raise KeyboardInterrupt
        return real_load(paths, **k)

    monkeypatch.setattr(describer_mod, "load_images", crash_on_second_batch)
    with pytest.raises(KeyboardInterrupt):
        describe_folder(folder, conf, out=out)
    monkeypatch.setattr(describer_mod, "load_images", real_load)
    (tmp_path / "o.pca.npz").unlink()
    with caplog.at_level(logging.INFO, logger="seqnet"):
        describe_folder(folder, conf, out=out)
    assert "fitted state" in caplog.text and "resuming" not in caplog.text
    assert h5_contents(out)[0].shape == (10, 3)


def test_cli_help_comes_from_the_tables(capsys):
    with pytest.raises(SystemExit):
        cli_main(["describe", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "{pixels,gem,gmp,netvlad,plugin}" in text
    assert "{efficientnet-lite0,efficientnet-lite1,efficientnet-lite2,vgg16}" in text
    assert "(default 8)" in text and "native for pixels; 640x320 for gem, gmp, netvlad" in text


@pytest.mark.parametrize("suffix", [".h5", ".npy"])
def test_output_copied_in_blocks_equals_one_written_at_once(folder, tmp_path, suffix, monkeypatch):
    import seqnet.describe.stage as store

    (folder / "f4.png").write_bytes(b"broken")  # skipped: the rows kept are not one run
    conf = DescribeConfig(skip_corrupted=True, batch_size=3)
    whole, names = describe_folder(folder, conf, out=tmp_path / f"a{suffix}")
    monkeypatch.setattr(store, "BLOCK_BYTES", 2 * 32 * 16 * 4)  # two rows a block (32x16 pixels)
    blocks, names_b = describe_folder(folder, conf, out=tmp_path / f"b{suffix}")
    assert names == names_b and len(names) == 9 and "f4.png" not in names
    np.testing.assert_array_equal(np.asarray(whole), np.asarray(blocks))
    if suffix == ".npy":
        assert isinstance(blocks, np.memmap)  # the output read back mapped, not held
        assert (tmp_path / "a.npy").read_bytes() == (tmp_path / "b.npy").read_bytes()


def test_dim_as_large_as_the_fit_images_is_refused(folder, tmp_path, capsys):
    assert describe(folder, "--method", "pixels", "--dim", "5", "--fit-on", "5", "--out", tmp_path / "p.npy") == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line or "Traceback" in line]
    assert len(err) == 1 and "--dim 5: the PCA is fitted on 5 images, and a PCA fitted on them has at most 4 axes" \
        in err[0] and "Traceback" not in err[0], err
    assert not (tmp_path / "p.npy").exists()
    assert describe(folder, "--method", "pixels", "--dim", "4", "--fit-on", "5", "--out", tmp_path / "p.npy") == 0
    assert np.load(tmp_path / "p.npy").shape == (10, 4)
