"""Tests of seqnet.describe and the `seqnet describe` command on tiny generated images."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch
from PIL import Image
from test_netvlad import make_checkpoint

import seqnet.describe.describers as describe_mod
from seqnet.cli import main
from seqnet.data.io import load_descriptors
from seqnet.describe.describers import describe_folder, describe_images, make_describer
from seqnet.errors import ConfigError, ImageError


@pytest.fixture
def folder(tmp_path):
    rng = np.random.default_rng(0)
    d = tmp_path / "imgs"
    d.mkdir()
    for i in range(10):
        Image.fromarray(rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8)).save(d / f"f{i}.png")
    return d


@pytest.mark.parametrize("method,opts,dim", [
    ("pixels", {}, 16 * 32),
    ("pixels", {"size": (16, 8), "crop_bottom": 4}, 128),
    ("gem", {"size": (64, 32)}, 1280),
    ("gmp", {"size": (64, 32), "layer": 10}, 112),
    ("netvlad", {"size": (64, 32), "clusters": 4, "layer": 10}, 4 * 112),
    ("pixels", {"dim": 5, "whiten": True}, 5),
])
def test_shapes_norms_determinism(folder, method, opts, dim):
    n = 10 if method == "pixels" else 4  # CNNs: few images keep the test fast
    paths = [folder / f"f{i}.png" for i in range(n)]
    kw = {"progress": False, "batch_size": 4, **opts}
    d1, names = describe_images(paths, method, **kw)
    d2, _ = describe_images(paths, method, **kw)
    assert d1.shape == (n, dim) and d1.dtype == np.float32
    assert names == [f"f{i}.png" for i in range(n)]
    np.testing.assert_allclose(np.linalg.norm(d1, axis=1), 1.0, rtol=1e-4)
    np.testing.assert_allclose(d1, d2, rtol=1e-5, atol=1e-6)


def test_batch_size_does_not_change_result(folder):
    paths = [folder / f"f{i}.png" for i in range(3)]
    d = make_describer("gem", size=(64, 32), batch_size=1, progress=False)
    a, _ = d.describe(paths)
    d.opts.batch_size = 3
    b, _ = d.describe(paths)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_one_describer_for_two_traverses(folder):
    paths = sorted(folder.iterdir())
    d = make_describer("pixels", paths, dim=3, progress=False)
    a, _ = d.describe(paths[:5])
    b, _ = d.describe(paths[5:])
    full, _ = d.describe(paths)
    np.testing.assert_allclose(np.vstack([a, b]), full, atol=1e-6)


@pytest.mark.parametrize("suffix", [".h5", ".npy"])
def test_output_readable_by_traverse_loader(folder, tmp_path, suffix):
    out = tmp_path / "trav" / f"descriptors{suffix}"
    desc, names = describe_folder(folder, "pixels", out=out, progress=False)
    loaded, h5_names = load_descriptors(out.parent)
    np.testing.assert_array_equal(loaded, desc)
    got = h5_names if suffix == ".h5" else (out.parent / "names.txt").read_text().splitlines()
    assert got == names
    assert not list(out.parent.glob(".*partial*"))
    with pytest.raises(ConfigError, match="already exists"):
        describe_folder(folder, "pixels", out=out, progress=False)


def test_resume_skips_finished_images(folder, tmp_path, monkeypatch):
    out = tmp_path / "out.h5"
    kw = {"dim": 4, "batch_size": 3, "progress": False}
    expected, _ = describe_folder(folder, "pixels", **kw)
    real_load = describe_mod.load_images
    loaded: list[str] = []

    def counting_load(paths, **k):
        loaded.extend(p.name for p in paths)
        if len(loaded) > 10 + 6:  # PCA fit (10 images) + 2 batches, then "crash"
            raise KeyboardInterrupt
        return real_load(paths, **k)

    monkeypatch.setattr(describe_mod, "load_images", counting_load)
    with pytest.raises(KeyboardInterrupt):
        describe_folder(folder, "pixels", out=out, **kw)
    assert not out.exists() and (tmp_path / ".out.h5.partial.h5").exists() and (tmp_path / "out.pca.npz").exists()
    with h5py.File(tmp_path / ".out.h5.partial.h5") as h:
        assert h["status"][()].tolist() == [1] * 6 + [0] * 4
    monkeypatch.setattr(describe_mod, "load_images", real_load)
    loaded.clear()
    monkeypatch.setattr(describe_mod, "load_images", lambda paths, **k: (loaded.extend(p.name for p in paths),
                                                                          real_load(paths, **k))[1])
    desc, names = describe_folder(folder, "pixels", out=out, **kw)
    assert loaded == [f"f{i}.png" for i in range(6, 10)]  # PCA reused, finished images skipped
    np.testing.assert_allclose(desc, expected, atol=1e-6)
    assert names == [f"f{i}.png" for i in range(10)]


def test_resume_with_other_settings_refused(folder, tmp_path):
    partial = tmp_path / ".out.h5.partial.h5"
    with h5py.File(partial, "w") as h:
        h.attrs["config"] = "{}"
        h.create_dataset("names", data=np.array(["x"], dtype=object), dtype=h5py.string_dtype())
        h.create_dataset("status", data=np.zeros(1, np.int8))
    with pytest.raises(ConfigError, match="other settings"):
        describe_folder(folder, "pixels", out=tmp_path / "out.h5", progress=False)
    describe_folder(folder, "pixels", out=tmp_path / "out.h5", progress=False, overwrite=True)


def test_corrupted_mixed_and_empty(folder, tmp_path):
    (folder / "f5.png").write_bytes(b"broken")
    with pytest.raises(ImageError, match="f5.png"):
        describe_folder(folder, "pixels", progress=False)
    desc, names = describe_folder(folder, "pixels", progress=False, skip_corrupted=True, batch_size=3)
    assert desc.shape[0] == 9 and "f5.png" not in names
    Image.fromarray(np.zeros((20, 32, 3), np.uint8)).save(folder / "f9.png")
    with pytest.raises(ImageError, match="f9.png has size 32x20"):
        describe_folder(folder, "pixels", progress=False, skip_corrupted=True, batch_size=3)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImageError, match="no images"):
        describe_folder(tmp_path / "empty", "pixels")
    with pytest.raises(ConfigError, match="unknown descriptor method 'sift'"):
        describe_images(sorted(folder.iterdir()), "sift")
    with pytest.raises(ConfigError, match="unknown describe option 'sise'"):
        describe_images(sorted(folder.iterdir()), "pixels", sise=3)


def test_cli_netvlad_checkpoint_and_errors(folder, tmp_path, capsys):
    ckpt = tmp_path / "pitts_WPCA8.pth.tar"
    make_checkpoint(ckpt)
    out = tmp_path / "nv.h5"
    assert main(["describe", str(folder), "--method", "netvlad", "--checkpoint", str(ckpt), "--resize", "32x32",
                 "--out", str(out), "--no-progress"]) == 0
    desc, names = load_descriptors_h5(out)
    assert desc.shape == (10, 8) and names[0] == "f0.png"
    assert main(["describe", str(folder), "--method", "gmp", "--checkpoint", str(ckpt), "--resize", "32x32",
                 "--out", str(tmp_path / "g.npy"), "--no-progress"]) == 0
    assert np.load(tmp_path / "g.npy").shape == (10, 16)
    bad = tmp_path / "bad.pth.tar"
    torch.save({"state_dict": {"pool.conv.weight": torch.zeros(2, 3, 1, 1)}}, bad)
    (folder / "f3.png").write_bytes(b"broken")
    capsys.readouterr()
    for args in (["--method", "netvlad", "--checkpoint", str(bad)], ["--method", "pixels"]):
        assert main(["describe", str(folder), *args, "--out", str(tmp_path / "x.h5"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and ("bad.pth.tar" in err[0] or "f3.png" in err[0]), err
    assert main(["describe", str(folder), "--method", "pixels", "--skip-corrupted", "--out", str(tmp_path / "x.h5"),
                 "--no-progress"]) == 0


def load_descriptors_h5(path):
    with h5py.File(path) as h:
        return h["descriptors"][()], [n.decode() for n in h["names"][()]]


def test_fit_sets(folder, tmp_path):
    from seqnet.describe.describers import fit_paths_of, make_options

    paths = sorted(folder.iterdir())
    assert fit_paths_of(make_options("pixels", fit=3), paths) == paths[:3]
    assert len(fit_paths_of(make_options("pixels", fit_max=4), paths)) == 4
    (tmp_path / "fit.txt").write_text("imgs/f1.png\nimgs/f2.png\n")
    assert [p.name for p in fit_paths_of(make_options("pixels", fit=str(tmp_path / "fit.txt")), paths)] == [
        "f1.png", "f2.png"]
    with pytest.raises(ConfigError, match=r"dims=3 must be between 1 and min\(N, D\) = min\(2, 512\)"):
        describe_images(paths, "pixels", dim=3, fit=2, progress=False)
