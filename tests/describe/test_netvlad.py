"""Tests of the NetVLAD layer, the VGG-16 encoder and Patch-NetVLAD checkpoint loading."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from conftest import mutated
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.core.errors import CheckpointError, ConfigError
from seqnet.describe.encoders import VGG16Encoder
from seqnet.describe.netvlad import NetVLAD, kmeans, load_netvlad, save_netvlad

TINY = (4, 8, 8, 16, 16)  # VGG-16 layout with narrow channels
VGG_CONV_KEYS = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]


def reference_netvlad(x: torch.Tensor, conv: torch.nn.Conv2d, centroids: torch.Tensor) -> torch.Tensor:
    """The loop implementation of pytorch-NetVlad (vladv2 flag = conv has a bias)."""
    n, c = x.shape[:2]
    k = centroids.shape[0]
    x = F.normalize(x, p=2, dim=1)
    a = F.softmax(conv(x).view(n, k, -1), dim=1)
    xf = x.view(n, c, -1)
    vlad = torch.zeros(n, k, c)
    for j in range(k):
        centre = centroids[j : j + 1, :].expand(xf.size(-1), -1, -1).permute(1, 2, 0).unsqueeze(0)
        residual = xf.unsqueeze(0).permute(1, 0, 2, 3) - centre
        residual = residual * a[:, j : j + 1, :].unsqueeze(2)
        vlad[:, j : j + 1, :] = residual.sum(dim=-1)
    vlad = F.normalize(vlad, p=2, dim=2).view(n, -1)
    return F.normalize(vlad, p=2, dim=1)


def make_checkpoint(path, k=4, wpca=8, bias=True, prefix="", drop=None):
    torch.manual_seed(0)
    enc = VGG16Encoder(TINY)
    pool = NetVLAD(k, TINY[-1], bias=bias)
    state = {f"encoder.{key}": v for key, v in enc.state_dict().items()}
    state.update({f"pool.{key}": v for key, v in pool.state_dict().items()})
    if wpca:
        state["WPCA.0.weight"] = torch.randn(wpca, k * TINY[-1], 1, 1) * 0.1
        state["WPCA.0.bias"] = torch.randn(wpca) * 0.1
    state = {k2.replace("encoder.", f"encoder.{prefix}"): v for k2, v in state.items() if k2 != drop}
    torch.save({"epoch": 1, "best_score": 0.5, "state_dict": state}, path)
    return state


def test_vgg16_layout_matches_pytorch_netvlad():
    enc = VGG16Encoder()
    shapes = {k: tuple(v.shape) for k, v in enc.state_dict().items()}
    assert sorted({int(k.split(".")[0]) for k in shapes}) == VGG_CONV_KEYS
    assert shapes["0.weight"] == (64, 3, 3, 3) and shapes["28.weight"] == (512, 512, 3, 3)
    assert len(enc) == 29 and not isinstance(enc[-1], torch.nn.ReLU)  # conv5_3 without ReLU and pool
    assert enc(torch.rand(1, 3, 32, 48)).shape == (1, 512, 2, 3)


@pytest.mark.parametrize("bias", [True, False])
def test_netvlad_matches_reference_loop(bias):
    torch.manual_seed(1)
    pool = NetVLAD(5, 6, bias=bias)
    x = torch.randn(2, 6, 3, 4)
    out = pool(x)
    assert out.shape == (2, 30)
    torch.testing.assert_close(out, reference_netvlad(x, pool.conv, pool.centroids), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(out.norm(dim=1), torch.ones(2))


def test_load_patch_netvlad_layout(tmp_path):
    ckpt = tmp_path / "pitts_WPCA8.pth.tar"
    state = make_checkpoint(ckpt)
    model = load_netvlad(ckpt)
    assert model.out_dim == 8 and model.pool.num_clusters == 4
    x = torch.rand(2, 3, 32, 32)
    with torch.no_grad():
        out = model(x)
        enc = VGG16Encoder(TINY)
        enc.load_state_dict({k[8:]: v for k, v in state.items() if k.startswith("encoder.")})
        pool = NetVLAD(4, 16, bias=True)
        pool.load_state_dict({k[5:]: v for k, v in state.items() if k.startswith("pool.")})
        v = reference_netvlad(enc(x), pool.conv, pool.centroids)
        expect = F.normalize(F.conv2d(v[:, :, None, None], state["WPCA.0.weight"], state["WPCA.0.bias"]).flatten(1))
    torch.testing.assert_close(out, expect, rtol=1e-4, atol=1e-5)
    assert load_netvlad(ckpt, use_wpca=False).out_dim == 64


def test_dataparallel_keys_and_save_round_trip(tmp_path):
    make_checkpoint(tmp_path / "dp.pth.tar", wpca=0, prefix="module.")
    model = load_netvlad(tmp_path / "dp.pth.tar")
    assert model.out_dim == 64
    again = load_netvlad(save_netvlad(model, tmp_path / "again.pth.tar"))
    x = torch.rand(1, 3, 16, 16)
    with torch.no_grad():
        torch.testing.assert_close(model(x), again(x))


@pytest.mark.parametrize("drop,match", [("pool.centroids", "needs pool.conv.weight and pool.centroids"),
                                        ("encoder.14.weight", "missing encoder.14.weight")])
def test_wrong_layout_names_file(tmp_path, drop, match):
    make_checkpoint(tmp_path / "bad.pth.tar", drop=drop)
    with pytest.raises(CheckpointError, match=match) as e:
        load_netvlad(tmp_path / "bad.pth.tar")
    assert "bad.pth.tar" in str(e.value)


def test_bad_wpca_garbage_and_missing(tmp_path):
    state = make_checkpoint(tmp_path / "w.pth.tar")
    state["WPCA.0.weight"] = torch.zeros(8, 63, 1, 1)
    torch.save({"state_dict": state}, tmp_path / "w.pth.tar")
    with pytest.raises(CheckpointError, match=r"WPCA.0.weight has shape \(8, 63, 1, 1\)"):
        load_netvlad(tmp_path / "w.pth.tar")
    (tmp_path / "junk.pth.tar").write_bytes(b"junk")
    with pytest.raises(CheckpointError, match="junk.pth.tar"):
        load_netvlad(tmp_path / "junk.pth.tar")
    torch.save({"state_dict": {"fc.weight": torch.zeros(2)}}, tmp_path / "other.pth.tar")
    with pytest.raises(CheckpointError, match="found top-level keys: fc"):
        load_netvlad(tmp_path / "other.pth.tar")
    with pytest.raises(CheckpointError, match="not found"):
        load_netvlad(tmp_path / "nope.pth.tar")


def test_init_from_kmeans_assigns_to_nearest_centre(rng):
    centres = np.eye(4, 8, dtype=np.float32)
    feats = np.repeat(centres, 20, axis=0) + 0.01 * rng.normal(size=(80, 8)).astype(np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    found = kmeans(feats, 4)
    pool = NetVLAD(4, 8)
    pool.init_from_clusters(found, feats)
    logits = pool.conv(torch.from_numpy(feats)[:, :, None, None])[:, :, 0, 0]
    nearest = np.argmax(feats @ found.T, axis=1)
    assert (logits.argmax(1).numpy() == nearest).all()
    with pytest.raises(ConfigError, match="at least 10 local features"):
        kmeans(feats[:5], 10)


class NotAllowed:  # pickled objects other than tensors and plain data must not load
    pass


def test_tags_arch_table_and_safe_loading(tmp_path):
    from seqnet.describe.encoders import EfficientNetLite
    from seqnet.describe.netvlad import NetVLADModel, checkpoint_tag

    model = NetVLADModel(EfficientNetLite(10, pretrained=False), NetVLAD(4, 112), arch="efficientnet-lite0")
    path = save_netvlad(model, tmp_path / "e.pth.tar", tag='{"output": "x.h5"}')
    again = load_netvlad(path)
    assert again.arch == "efficientnet-lite0" and again.encoder.layer == 10 and again.out_dim == 4 * 112
    assert checkpoint_tag(path) == '{"output": "x.h5"}'
    make_checkpoint(tmp_path / "p.pth.tar")
    (tmp_path / "junk.pth.tar").write_text("my model\n")
    assert checkpoint_tag(tmp_path / "p.pth.tar") is None and checkpoint_tag(tmp_path / "junk.pth.tar") is None
    state = make_checkpoint(tmp_path / "r.pth.tar")
    torch.save({"state_dict": state, "arch": "resnet"}, tmp_path / "r.pth.tar")
    with pytest.raises(CheckpointError, match="unknown encoder arch .resnet.; valid: efficientnet-lite0, "
                                              "efficientnet-lite1, efficientnet-lite2, vgg16"):
        load_netvlad(tmp_path / "r.pth.tar")
    torch.save({"state_dict": state, "extra": NotAllowed()}, tmp_path / "code.pth.tar")
    with pytest.raises(CheckpointError, match="cannot read NetVLAD checkpoint .*code.pth.tar"):
        load_netvlad(tmp_path / "code.pth.tar")


def _set(key, value):
    return lambda state, top: state.__setitem__(key, value)


def _top(key, value):
    return lambda state, top: top.__setitem__(key, value)


def _widen(state, top):  # two 1-D "conv weights" would make VGG-16 build a 10**6 x 10**6 conv (36 TB)
    state["encoder.12.weight"] = torch.zeros(1_000_000)
    state["encoder.14.weight"] = torch.zeros(1_000_000)


def _wide_conv(state, top):  # 4-D but not what the widths call for
    state["encoder.12.weight"] = torch.zeros(100_000, 1, 1, 1)


@pytest.mark.parametrize("edit, match", [
    (_set("pool.centroids", torch.zeros(64)), r"pool.centroids has shape \(64,\), expected \[K, C\]"),
    (_set("pool.centroids", [1.0, 2.0]), r"'state_dict' must map parameter names to tensors; 'pool.centroids' maps "
                                         r"to list"),
    (_set("pool.centroids", torch.zeros(0, 16)), r"pool.centroids' K \(clusters\) must be an integer in 1\.\.1048576"),
    (_set("pool.conv.weight", torch.zeros(3, 16, 1, 1)), r"pool.conv.weight has shape \(3, 16, 1, 1\), expected "
                                                        r"\[4, 16, 1, 1\] \(NetVLAD of 4 clusters x 16-D\)"),
    (_set("pool.extra", torch.zeros(1)), r"pool.extra is not a weight of NetVLAD"),
    (_set(5, torch.zeros(1)), r"'5' maps to Tensor"),
    (_top("arch", ["vgg16"]), r"unknown encoder arch \"\['vgg16'\]\""),
    (_top("arch", {"x": 1}), r"unknown encoder arch"),
    (_widen, r"encoder.14.weight has shape \(1000000,\), expected a conv weight \[out, in, 3, 3\]"),
    (_wide_conv, r"encoder.12.weight has shape \(100000, 1, 1, 1\), expected \[8, 8, 3, 3\] \(VGG-16 of widths"),
    (_set("WPCA.0.weight", torch.zeros(64)), r"WPCA.0.weight has shape \(64,\), expected \[P, 64, 1, 1\]"),
    (_set("WPCA.0.bias", torch.zeros(9)), r"WPCA.0.bias has shape \(9,\), expected \[8\]"),
])
def test_hostile_checkpoint_is_one_checkpoint_error(tmp_path, edit, match):
    """1-D or non-tensor centroids (ValueError / AttributeError before), an arch that is a list (TypeError),
    and shapes that would build layers larger than the file (a 36 TB VGG conv): every shape is checked in
    range and against the stored tensors before any layer is built."""
    state, top = make_checkpoint(tmp_path / "h.pth.tar"), {}
    edit(state, top)
    torch.save({"state_dict": state, **top}, tmp_path / "h.pth.tar")
    with pytest.raises(CheckpointError, match=match):
        load_netvlad(tmp_path / "h.pth.tar")


@pytest.mark.parametrize("layer", [[1], True, "99", 3.5, "head; rm -rf"])
def test_lite_layer_from_a_checkpoint_is_validated(tmp_path, layer):
    from seqnet.describe.encoders import EfficientNetLite
    from seqnet.describe.netvlad import NetVLADModel

    model = NetVLADModel(EfficientNetLite(10, pretrained=False), NetVLAD(4, 112), arch="efficientnet-lite0")
    path = save_netvlad(model, tmp_path / "e.pth.tar")
    ckpt = torch.load(path, weights_only=True)
    ckpt["layer"] = layer
    torch.save(ckpt, path)
    with pytest.raises(CheckpointError, match=r"the checkpoint's layer: unknown efficientnet-lite0 layer"):
        load_netvlad(path)
    ckpt["layer"] = 9  # a valid block, but the weights are block 10's
    torch.save(ckpt, path)
    with pytest.raises(CheckpointError, match=r"encoder.blocks.10.* is not a weight of efficientnet-lite0 cut at 9"):
        load_netvlad(path)


def test_stored_image_size_is_bounded(tmp_path):
    from seqnet.describe.netvlad import checkpoint_image_size

    state = make_checkpoint(tmp_path / "s.pth.tar")
    for size, expect in (([640, 480], (640, 480)), ([10**9, 10**9], None), ([True, 2], None), ("640x480", None)):
        torch.save({"state_dict": state, "image_size": size}, tmp_path / "s.pth.tar")
        assert checkpoint_image_size(tmp_path / "s.pth.tar") == expect


@pytest.mark.parametrize("tag", ['{"provenance_fit": "abc", "settings": ["method", "netvlad"]}',
                                 '{"provenance_fit": ["abc"], "settings": {}}', '[1, 2]', '"x"', "{" * 100_000])
def test_a_reused_state_tag_of_the_wrong_shape_is_not_reused(tmp_path, tag):
    """The tag of a reused NetVLAD state is read from its file: ``settings`` a list was an AttributeError."""
    from seqnet.describe import DescribeConfig
    from seqnet.describe.encoders import EfficientNetLite
    from seqnet.describe.netvlad import NetVLADModel
    from seqnet.describe.state import reused_fit

    model = NetVLADModel(EfficientNetLite(10, pretrained=False), NetVLAD(4, 112), arch="efficientnet-lite0")
    path = save_netvlad(model, tmp_path / "e.pth.tar", tag=tag)
    conf = DescribeConfig(method="netvlad", checkpoint=str(path)).resolved()
    assert reused_fit(conf) is None


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_checkpoint_loads_or_is_one_error(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("ck") / "f.pth.tar"
    f.write_bytes(data.draw(mutated(FUZZ_CHECKPOINT, max_flips=4)))
    try:
        model = load_netvlad(f)
    except CheckpointError:
        return
    assert model.out_dim in (8, 64)


def _fuzz_checkpoint() -> bytes:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        make_checkpoint(Path(d) / "c.pth.tar")
        return (Path(d) / "c.pth.tar").read_bytes()


FUZZ_CHECKPOINT = _fuzz_checkpoint()
