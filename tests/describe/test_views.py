"""Photometric views (:mod:`seqnet.describe.views`): histogram equalisation against Pillow's, image by image, and
descriptors of several views concatenated."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image, ImageOps

from seqnet.core.errors import ConfigError
from seqnet.core.provenance import make
from seqnet.describe import DescribeConfig, make_describer
from seqnet.describe.views import check_views, described_views, equalize


def _pillow(images: np.ndarray) -> np.ndarray:
    """The naive reference: Pillow's ImageOps.equalize, one image at a time."""
    return np.stack([np.asarray(ImageOps.equalize(Image.fromarray(im))) for im in images])


@settings(max_examples=200, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 3), st.integers(1, 7), st.integers(1, 7), st.sampled_from([1, 3]))),
       st.sampled_from(["any", "few", "bright", "flat"]))
def test_equalize_is_pillows_equalize(images, kind):
    if kind == "few":  # two or three levels: a small step
        images = (images % 3) * 100
    elif kind == "bright":
        images = 250 + images % 6
    elif kind == "flat":  # one level: left as it is
        images = np.broadcast_to(images[:, :1, :1], images.shape).copy()
    images = images[..., 0] if images.shape[-1] == 1 else images  # grey [B, H, W] too
    assert np.array_equal(equalize(images), _pillow(images))


def test_equalize_edge_cases():
    assert equalize(np.zeros((0, 4, 4, 3), np.uint8)).shape == (0, 4, 4, 3)
    one = np.array([[[0, 255]]], np.uint8)  # two pixels, two levels
    assert np.array_equal(equalize(one), _pillow(one))
    with pytest.raises(ConfigError, match="uint8"):
        equalize(np.zeros((1, 2, 2), np.float32))


def test_views_are_checked():
    assert check_views("raw, equalize") == ("raw", "equalize")
    for bad, said in (("raw,sharpen", "unknown view 'sharpen'"), ("raw,raw", "a view given twice"), ((), "no view")):
        with pytest.raises(ConfigError, match=said):
            check_views(bad)


def test_views_are_concatenated_normalised_in_order():
    rng = np.random.default_rng(0)
    images = rng.integers(0, 120, (4, 6, 8, 3), dtype=np.uint8)  # dim: equalising changes them

    def extract(view, x):
        return x.reshape(len(x), -1)[:, :5].astype(np.float32) + (1 if view == "raw" else 2)

    both = described_views(images, ("raw", "equalize"), extract)
    assert both.shape == (4, 10) and np.allclose(np.linalg.norm(both, axis=1), 1, atol=1e-6)
    raw, eq = extract("raw", images), extract("equalize", equalize(images))  # each view its own extract
    for part, want in ((both[:, :5], raw), (both[:, 5:], eq)):
        want = want / np.linalg.norm(want, axis=1, keepdims=True) / np.sqrt(2)
        assert np.allclose(part, want, atol=1e-6)
    assert np.array_equal(described_views(images, ("raw",), extract), raw)  # one view: extract itself


def test_default_views_leave_the_settings_and_ids_unchanged():
    plain = DescribeConfig(method="pixels")
    assert "views" not in plain.settings()  # descriptors made before views keep their provenance id
    viewed = plain.replace(views=("raw", "equalize"))
    assert viewed.settings()["views"] == ["raw", "equalize"]
    assert make("describe", plain.settings())["id"] != make("describe", viewed.settings())["id"]


def test_a_describer_with_views_describes_each_view(tmp_path):
    rng = np.random.default_rng(1)
    paths = []
    for i in range(3):
        paths.append(tmp_path / f"{i}.png")
        Image.fromarray(rng.integers(0, 90, (16, 32, 3), dtype=np.uint8)).save(paths[-1])
    conf = DescribeConfig(method="pixels", patch=0, size="native")
    plain, _ = make_describer(conf).describe(paths)
    both, names = make_describer(conf.replace(views=("raw", "equalize"))).describe(paths)
    assert both.shape == (3, 2 * plain.shape[1]) and names == ["0.png", "1.png", "2.png"]
    assert np.allclose(both[:, : plain.shape[1]] * np.sqrt(2), plain / np.linalg.norm(plain, axis=1, keepdims=True),
                       atol=1e-5)


def _netvlad_views_command(tmp_path, seed: int) -> list[str]:
    """Four random 80x40 images in tmp_path/imgs and the describe command (no --out) of two-view NetVLAD."""
    rng = np.random.default_rng(seed)
    (tmp_path / "imgs").mkdir()
    for i in range(4):
        Image.fromarray((rng.random((40, 80, 3)) ** 3 * 255).astype(np.uint8)).save(tmp_path / "imgs" / f"{i}.png")
    return ["-q", "describe", str(tmp_path / "imgs"), "--method", "netvlad", "--clusters", "4", "--batch-size", "2",
            "--resize", "64x32", "--views", "raw,equalize"]


def test_netvlad_fits_clusters_per_view_keeps_them_and_reuses_them(tmp_path, caplog):
    """Each view fits its own NetVLAD clusters (one set fitted on both views was worse on Nordland64's val), kept
    beside the output as <stem>.netvlad.pth.tar and <stem>.equalize.netvlad.pth.tar and reused by a second run; a
    seqnet-fitted checkpoint of one view is refused with several views."""
    import logging

    import h5py

    from seqnet.cli import main as cli_main
    from seqnet.describe.netvlad import load_netvlad

    base = _netvlad_views_command(tmp_path, seed=0)
    assert cli_main([*base, "--out", str(tmp_path / "nv.h5")]) == 0
    raw, eq = (load_netvlad(tmp_path / f"nv{v}.netvlad.pth.tar") for v in ("", ".equalize"))
    assert not np.allclose(raw.pool.centroids.detach().numpy(), eq.pool.centroids.detach().numpy())
    with h5py.File(tmp_path / "nv.h5") as h:
        first = h["descriptors"][()]
    conf = DescribeConfig(method="netvlad", clusters=4, batch_size=2, size=(64, 32), views=("raw", "equalize"))
    paths = sorted((tmp_path / "imgs").iterdir())
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="seqnet"):
        again, _ = make_describer(conf, paths, sidecar=tmp_path / "nv.h5").describe(paths)
    assert sum("reusing the NetVLAD clusters" in r.getMessage() for r in caplog.records) == 2
    np.testing.assert_allclose(again, first, atol=1e-5)
    with pytest.raises(ConfigError, match="fits one per view"):
        make_describer(conf.replace(checkpoint=str(tmp_path / "nv.netvlad.pth.tar")), paths)


def test_one_view_checkpoint_refusal_names_the_fit_on_route_which_works(tmp_path):
    """A --checkpoint seqnet fitted for one view is refused with --views; the hint names --fit-on with the images
    that state was fitted on (docs/describe.md#views), and following it gives the same provenance id."""
    from seqnet.cli import main as cli_main
    from seqnet.data.readers import read_provenance

    base = _netvlad_views_command(tmp_path, seed=1)
    assert cli_main([*base, "--out", str(tmp_path / "r.h5")]) == 0
    conf = DescribeConfig(method="netvlad", clusters=4, batch_size=2, size=(64, 32), views=("raw", "equalize"),
                          checkpoint=str(tmp_path / "r.netvlad.pth.tar"))
    with pytest.raises(ConfigError) as e:
        make_describer(conf, sorted((tmp_path / "imgs").iterdir()))
    assert "hint: drop --checkpoint and pass --fit-on the 4 images r.h5 was fitted on (their folder or list file)" \
        in str(e.value) and "seqnet dataset from-images" in str(e.value)
    assert cli_main([*base, "--fit-on", str(tmp_path / "imgs"), "--out", str(tmp_path / "q.h5")]) == 0
    assert read_provenance(tmp_path / "q.h5")["id"] == read_provenance(tmp_path / "r.h5")["id"]


def test_fit_and_describe_lines_name_the_view(tmp_path, caplog):
    """Several views fit one state each: each NetVLAD fit line names its view (one view: as before); the describe
    line names the views beside the D they double."""
    import logging

    from seqnet.describe.stage import describe_folder

    rng = np.random.default_rng(2)
    (tmp_path / "imgs").mkdir()
    for i in range(3):
        Image.fromarray((rng.random((40, 80, 3)) * 255).astype(np.uint8)).save(tmp_path / "imgs" / f"{i}.png")
    paths = sorted((tmp_path / "imgs").iterdir())
    conf = DescribeConfig(method="netvlad", clusters=2, batch_size=3, size=(64, 32))
    two = ["NetVLAD (raw view): 2 clusters", "NetVLAD (equalize view): 2 clusters"]
    for views, want in ((("raw",), ["NetVLAD: 2 clusters"]), (("raw", "equalize"), two)):
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="seqnet"):
            make_describer(conf.replace(views=views), paths)
        fits = [r.getMessage() for r in caplog.records if "clusters from" in r.getMessage()]
        assert [f.split(" from")[0] for f in fits] == want
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="seqnet"):
        describe_folder(tmp_path / "imgs", DescribeConfig(method="pixels", size=(8, 4), views=("raw", "equalize")))
    assert any("3 descriptors of dim 64 (pixels, views raw,equalize)" in r.getMessage() for r in caplog.records)
