"""Tests of the describe API: DescribeConfig, the DESCRIBERS table and the Describer, on tiny generated images."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seqnet.core.errors import ConfigError, ImageError
from seqnet.describe import BACKBONES, DESCRIBERS, DescribeConfig, describe_folder, describe_images, make_describer
from seqnet.describe.describer import fit_paths_of

# per method: tiny settings and the descriptor dimension they give on 64x32 RGB / native 32x16 images
TINY = {
    "pixels": ({}, 16 * 32),
    "gem": ({"size": (64, 32)}, 1280),
    "gmp": ({"size": (64, 32), "layer": 10}, 112),
    "netvlad": ({"size": (64, 32), "clusters": 4}, 4 * 112),
    "plugin": ({"describer": "describe.plugin_describer:make"}, 12),  # tests/describe/plugin_describer.py
}


def test_tiny_settings_cover_the_table():
    assert set(TINY) == set(DESCRIBERS)


@pytest.mark.parametrize("method", list(DESCRIBERS))
def test_every_describer_shape_dtype_norm_determinism(folder, method):
    opts, dim = TINY[method]
    n = 10 if method == "pixels" else 4  # CNNs: few images keep the test fast
    paths = [folder / f"f{i}.png" for i in range(n)]
    conf = DescribeConfig(method=method, batch_size=2, device="cpu", **opts)
    d1, names = describe_images(paths, conf)
    d2, _ = describe_images(paths, conf)
    assert d1.shape == (n, dim) and d1.dtype == np.float32
    assert names == [f"f{i}.png" for i in range(n)]
    np.testing.assert_allclose(np.linalg.norm(d1, axis=1), 1.0, rtol=1e-4)
    np.testing.assert_allclose(d1, d2, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("opts,dim", [({"size": (16, 8), "crop_bottom": 4}, 128), ({"dim": 5, "whiten": True}, 5),
                                      ({"size": "16x8"}, 128)])
def test_pixels_options(folder, opts, dim):
    desc, _ = describe_images(sorted(folder.iterdir()), DescribeConfig(**opts))
    assert desc.shape == (10, dim)
    np.testing.assert_allclose(np.linalg.norm(desc, axis=1), 1.0, rtol=1e-4)


def test_describer_call_load_and_config(folder):
    paths = sorted(folder.iterdir())[:3]
    grey = make_describer(DescribeConfig(crop_bottom=4))
    assert grey.config.size == "native" and grey.method == "pixels"
    imgs = grey.load(paths)
    assert imgs.shape == (3, 12, 32) and imgs.dtype == np.uint8
    np.testing.assert_array_equal(grey(imgs), grey.describe(paths)[0])
    rgb = make_describer(DescribeConfig(method="gmp", size=(64, 32), layer=10, device="cpu"))
    assert rgb.config.size == (64, 32) and rgb.load(paths).shape == (3, 32, 64, 3)
    assert make_describer(DescribeConfig(method="gem", device="cpu")).config.size == (640, 320)  # "auto"
    (folder / "f0.png").write_bytes(b"broken")
    skipping = make_describer(DescribeConfig(skip_corrupted=True))
    with pytest.raises(ImageError, match="f0.png"):  # load keeps rows aligned with paths: never skips
        skipping.load(paths)
    assert skipping.load_some(paths)[1] == [0]


def test_native_size_is_native_for_cnn_methods(folder):
    paths = sorted(folder.iterdir())[:2]
    d = make_describer(DescribeConfig(method="gmp", size="native", layer=10, device="cpu"))
    assert d.config.size == "native" and d.config.settings()["size"] == "native"
    assert d.load(paths).shape == (2, 16, 32, 3)  # not resized to 640x320
    np.testing.assert_allclose(d.describe(paths)[0], d(d.load(paths)), atol=1e-6)


def test_batch_size_does_not_change_result(folder):
    paths = [folder / f"f{i}.png" for i in range(3)]
    conf = DescribeConfig(method="gem", size=(64, 32), batch_size=1, device="cpu")
    a, _ = make_describer(conf).describe(paths)
    b, _ = make_describer(conf.replace(batch_size=3)).describe(paths)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_one_describer_for_two_traverses(folder):
    paths = sorted(folder.iterdir())
    d = make_describer(DescribeConfig(dim=3), paths)
    a, _ = d.describe(paths[:5])
    b, _ = d.describe(paths[5:])
    full, _ = d.describe(paths)
    np.testing.assert_allclose(np.vstack([a, b]), full, atol=1e-6)


def test_corrupted_mixed_and_empty(folder, tmp_path):
    (folder / "f5.png").write_bytes(b"broken")
    with pytest.raises(ImageError, match="f5.png"):
        describe_folder(folder, DescribeConfig())
    desc, names = describe_folder(folder, DescribeConfig(skip_corrupted=True, batch_size=3))
    assert desc.shape[0] == 9 and "f5.png" not in names
    Image.fromarray(np.zeros((20, 32, 3), np.uint8)).save(folder / "f9.png")
    with pytest.raises(ImageError, match="f9.png has size 32x20"):
        describe_folder(folder, DescribeConfig(skip_corrupted=True, batch_size=3))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImageError, match="no images"):
        describe_folder(tmp_path / "empty", DescribeConfig())


def test_fit_sets(folder, tmp_path):
    paths = sorted(folder.iterdir())
    assert fit_paths_of(DescribeConfig(fit=3), paths) == paths[:3]
    assert len(fit_paths_of(DescribeConfig(fit_max=4), paths)) == 4
    (tmp_path / "fit.txt").write_text("imgs/f1.png\nimgs/f2.png\n")
    assert [p.name for p in fit_paths_of(DescribeConfig(fit=tmp_path / "fit.txt"), paths)] == ["f1.png", "f2.png"]
    assert DescribeConfig(fit=paths[:2]).fit == (str(paths[0]), str(paths[1]))
    with pytest.raises(ConfigError, match=r"--dim 3: the PCA is fitted on 2 images, .* at most 1 axes"):
        describe_images(paths, DescribeConfig(dim=3, fit=2))


# ----------------------------------------------------------------------------- DescribeConfig


def test_config_defaults_normalising_and_round_trip():
    conf = DescribeConfig(method="gem", size="64X32", layer="10", fit="train/")
    assert conf.size == (64, 32) and conf.layer == 10 and conf.image_size == (64, 32)
    assert DescribeConfig.from_dict(conf.to_dict()) == conf
    assert DescribeConfig().size == "auto" and DescribeConfig().image_size is None
    assert DescribeConfig(size=[32, 16]).size == (32, 16) and DescribeConfig(size="NATIVE").size == "native"
    assert DescribeConfig(size=(8192, 1)).size == (8192, 1)
    assert conf.merge(size=None, dim=4).size == (64, 32)  # None keeps (the CLI's merge)
    assert DescribeConfig(method="gem", checkpoint="x.pth.tar", backbone="vgg16").backbone == "vgg16"


@pytest.mark.parametrize("kwargs,match", [
    ({"method": "sift"}, "unknown descriptor method 'sift'; valid: pixels, gem, gmp, netvlad"),
    ({"backbone": "resnet"}, "unknown backbone 'resnet'; valid: efficientnet-lite0, efficientnet-lite1, "
                             "efficientnet-lite2, vgg16"),
    ({"batch_size": 0}, "batch-size must be an integer >= 1"),
    ({"crop_bottom": -1}, "crop-bottom must be an integer >= 0"),
    ({"patch": -1}, "patch must be an integer >= 0"),
    ({"dim": 0}, "output dim must be an integer >= 1"),
    ({"gem_p": 0}, "GeM power p must be a number > 0"),
    ({"clusters": 0}, "clusters must be an integer >= 1"),
    ({"fit_max": 0}, "fit-max must be an integer >= 1"),
    ({"seed": -1}, "seed must be an integer >= 0"),
    ({"size": (0, 32)}, "size must be 'auto', 'native', 'keep-aspect:W' or WIDTHxHEIGHT with both in 1..8192"),
    ({"size": "keep-aspect:0"}, "keep-aspect:W needs a width W in 1..8192"),
    ({"size": (9000, 32)}, r"in 1..8192 \(e.g. 640x320\), got \(9000, 32\)"),
    ({"size": "big"}, "got 'big'"),
    ({"size": None}, "got None"),
    ({"size": (64, 32, 3)}, "WIDTHxHEIGHT"),
    ({"layer": 16}, "unknown efficientnet-lite0 layer 16; valid: 'head' or a block index 0..15"),
    ({"backbone": "vgg16", "layer": 3, "checkpoint": "c.pth"}, "unknown vgg16 layer 3; valid: none"),
    ({"method": "gem", "backbone": "vgg16"}, "vgg16 backbone ships no weights"),
    ({"method": "netvlad", "backbone": "vgg16"}, "NetVLAD without a checkpoint needs a pretrained backbone"),
    ({"fit": 0}, r"fit \(the first N images\) must be an integer >= 1"),
    ({"fit": []}, "fit must be an int N >= 1, a folder or list file, or a non-empty list"),
    ({"use_wpca": "no"}, "use-wpca must be true or false"),
    ({"device": "tpu"}, "unknown device 'tpu'"),
])
def test_config_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        DescribeConfig(**kwargs)


def test_config_unknown_key_names_valid_ones():
    with pytest.raises(ConfigError, match="unknown DescribeConfig key 'sise'; valid: method, size"):
        DescribeConfig.from_dict({"sise": 3})
    with pytest.raises(ConfigError, match="unknown DescribeConfig key 'progress'"):
        DescribeConfig().replace(progress=False)


def test_settings_follow_the_method():
    assert DescribeConfig().settings() == {"method": "pixels", "size": "native", "crop_bottom": 0, "patch": 8}
    nv = DescribeConfig(method="netvlad", dim=4, fit=["a.png", "b.png"]).settings()
    assert nv["size"] == [640, 320] and nv["clusters"] == 64 and nv["dim"] == 4 and "gem_p" not in nv
    assert nv["fit"]["paths"] == 2  # a list of fitting images is stored as its length and hash
    assert "checkpoint" in DescribeConfig(method="gem").settings()


def test_backbones_table():
    assert BACKBONES["efficientnet-lite0"].check_layer("head") == "head"
    assert BACKBONES["efficientnet-lite0"].check_layer("3") == 3
    enc = BACKBONES["efficientnet-lite0"].build(10)
    assert (enc.arch, enc.out_dim, enc.stride) == ("efficientnet-lite0", 112, 16)
    assert BACKBONES["vgg16"].build(pretrained=False).out_dim == 512
    assert not BACKBONES["vgg16"].pretrained and BACKBONES["efficientnet-lite0"].local_layer == 10


def test_keep_aspect_resizes_to_the_width_keeping_the_ratio(tmp_path):
    from PIL import Image

    from seqnet.describe import DescribeConfig, make_describer

    paths = []
    for i in range(2):
        p = tmp_path / f"w{i}.png"
        Image.fromarray(np.full((30, 90, 3), 40 * i, np.uint8)).save(p)
        paths.append(p)
    conf = DescribeConfig(method="pixels", size="keep-aspect:45", patch=0)
    d = make_describer(conf, paths)
    assert d.load(paths).shape == (2, 15, 45) and conf.resolved().size == "keep-aspect:45"
    assert d.describe(paths)[0].shape == (2, 15 * 45)


def test_netvlad_checkpoint_keeps_its_image_size(tmp_path, capsys):
    """A NetVLAD fitted by seqnet stores its image size; --checkpoint without --resize describes at it."""
    import json

    import h5py
    from PIL import Image

    from seqnet.cli import main as cli_main

    rng = np.random.default_rng(0)
    (tmp_path / "imgs").mkdir()
    for i in range(4):
        Image.fromarray((rng.random((40, 80, 3)) * 255).astype(np.uint8)).save(tmp_path / "imgs" / f"{i}.png")
    base = ["-q", "describe", str(tmp_path / "imgs"), "--method", "netvlad", "--clusters", "4", "--batch-size", "2"]
    assert cli_main([*base, "--resize", "64x32", "--out", str(tmp_path / "nv.h5")]) == 0
    ckpt = tmp_path / "nv.netvlad.pth.tar"
    assert cli_main([*base, "--checkpoint", str(ckpt), "--out", str(tmp_path / "again.h5")]) == 0
    with h5py.File(tmp_path / "again.h5") as h:
        assert json.loads(h.attrs["provenance"])["settings"]["size"] == [64, 32]
        again = h["descriptors"][()]
    with h5py.File(tmp_path / "nv.h5") as h:
        np.testing.assert_allclose(again, h["descriptors"][()], atol=1e-5)


def test_a_plugin_describer_runs_and_is_recorded(folder, tmp_path):
    import json

    import h5py

    from seqnet.cli import main as cli_main
    from seqnet.core.errors import ConfigError

    spec = "describe.plugin_describer:make"
    assert cli_main(["-q", "describe", str(folder), "--method", "plugin", "--describer", spec, "--device", "cpu",
                     "--out", str(tmp_path / "p.h5")]) == 0
    with h5py.File(tmp_path / "p.h5") as h:
        prov = json.loads(h.attrs["provenance"])
        assert h["descriptors"].shape == (10, 12)
    assert prov["settings"]["describer"] == spec and prov["settings"]["size"] == [32, 16]
    assert prov["settings"]["describer_provenance"] == {"weights": "none", "version": 1}
    assert cli_main(["-q", "dataset", "from-images", str(folder), str(folder), "--method", "plugin", "--describer",
                     spec, "--frame-aligned", "--radius", "1", "--out", str(tmp_path / "ds")]) == 0
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text())["provenance"]["reference"]["dim"] == 12
    assert cli_main(["-q", "describe", str(folder), "--method", "pixels", "--out", str(tmp_path / "x.h5")]) == 0
    from seqnet.core.provenance import ProvenanceError, check_same
    from seqnet.data.readers import read_provenance

    with pytest.raises(ProvenanceError, match="were made differently: describer: .*method: \"plugin\" vs \"pixels\""):
        check_same(read_provenance(tmp_path / "p.h5"), read_provenance(tmp_path / "x.h5"), "ref", "query")
    for bad, msg in (("describe.plugin_describer:nope", "cannot import it"), ("nocolon", "expected 'package"),
                     ("describe.plugin_describer:not_a_module", "not a torch.nn.Module")):
        with pytest.raises(ConfigError, match=msg):
            DescribeConfig(method="plugin", describer=bad).settings()
    with pytest.raises(ConfigError, match="needs --describer"):
        DescribeConfig(method="plugin")
    with pytest.raises(ConfigError, match="--describer goes with --method plugin"):
        DescribeConfig(method="pixels", describer=spec)


def test_spilled_descriptors_equal_the_held_ones(folder, monkeypatch):
    from seqnet.core.memmaps import Spilled

    (folder / "f5.png").write_bytes(b"broken")
    d = make_describer(DescribeConfig(skip_corrupted=True, batch_size=3))
    paths = sorted(folder.iterdir())
    held, names = d.describe(paths, spill=True)  # small: held
    assert not isinstance(held, Spilled) and len(names) == 9 and "f5.png" not in names
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")
    spilled, names_s = d.describe(paths, spill=True)
    assert isinstance(spilled, Spilled) and names_s == names
    np.testing.assert_array_equal(np.asarray(spilled), held)
    assert not isinstance(d.describe(paths)[0], Spilled)  # only when asked


def test_skipped_images_are_counted_in_the_singular_and_plural(folder, caplog):
    """'skipped 1 unreadable image(s)' is now 'skipped 1 unreadable image' / 'skipped 2 unreadable images'."""
    import logging

    caplog.set_level(logging.WARNING, logger="seqnet")
    (folder / "f5.png").write_bytes(b"broken")
    d = make_describer(DescribeConfig(skip_corrupted=True, batch_size=20))
    d.describe(sorted(folder.iterdir()))
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["skipped 1 unreadable image"]
    caplog.clear()
    (folder / "f6.png").write_bytes(b"broken")
    d.describe(sorted(folder.iterdir()))
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["skipped 2 unreadable images"]
