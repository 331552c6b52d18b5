"""Images posted as PNG / JPEG: described as the map was (its describer rebuilt), refused when damaged or too big."""

from __future__ import annotations

import io
import zlib

import numpy as np
import pytest
from conftest import image_folder, serving

from seqnet.client import Client, ClientError


@pytest.fixture(scope="module")
def image_service(tmp_path_factory):
    """A map of 30 random 32x16 images described by ``pixels`` (native size), served with L = 3."""
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.describe import DescribeConfig, make_describer
    from seqnet.describe.stage import describe_provenance
    from seqnet.localize.config import LocalizeConfig
    from seqnet.serve.service import load_service

    d = tmp_path_factory.mktemp("images")
    folder = image_folder(d / "imgs", n=30, seed=3)
    conf = DescribeConfig(method="pixels", patch=8, size="native")
    paths = sorted(folder.iterdir(), key=lambda p: int(p.stem[1:]))
    ref, names = make_describer(conf).describe(paths)
    pos = np.c_[np.arange(len(names)) * 2.0, np.zeros(len(names))]
    t = Traverse(ref, pos, names=names, provenance=describe_provenance(conf, None, ref))
    save_dataset(Dataset(t, t, 3.0), d / "map")
    service = load_service(LocalizeConfig(method="raw+seqmatch", seq_len=3, device="cpu"), d / "map")
    return service, paths


def test_png_and_jpeg_frames_equal_their_descriptors(image_service):
    service, paths = image_service
    assert service.describer is not None
    with serving(service) as (url, api):
        client = Client(url)
        with client.session() as by_image, client.session() as by_descriptor:
            for p in paths[4:12]:
                a = by_image.send(p)  # a path: its bytes, sent as image/png
                b = by_descriptor.send(service.describer(service.describer.load([p]))[0])
                assert {k: v for k, v in a.items() if k != "latency_ms"} == \
                       {k: v for k, v in b.items() if k != "latency_ms"}
            assert a["estimate_name"] == paths[11].name and a["position"] == [22.0, 0.0]
            from PIL import Image

            buf = io.BytesIO()
            Image.open(paths[12]).save(buf, "JPEG", quality=95)
            assert by_image.send(buf.getvalue())["frame"] == 8
        assert 500 not in api.metrics.requests


def big_png(w: int, h: int) -> bytes:
    """A valid PNG header declaring ``w`` x ``h`` grey pixels, with a small compressed body."""
    def chunk(kind, data):
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")
    raw = zlib.compress(b"\x00" * (w + 1) * 64)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", w.to_bytes(4, "big") + h.to_bytes(4, "big") + b"\x08\x00\x00\x00\x00")
            + chunk(b"IDAT", raw) + chunk(b"IEND", b""))


def test_damaged_mislabelled_and_huge_images_are_400(image_service):
    service, paths = image_service
    png = paths[0].read_bytes()
    cases = {"truncated": (png[: len(png) // 2], "image/png"),
             "garbage": (b"\x89PNG\r\n\x1a\n" + bytes(50), "image/png"),
             "png as jpeg": (png, "image/jpeg"), "huge": (big_png(5000, 5000), "image/png"),
             "wrong size": (big_png(16, 8), "image/png")}
    with serving(service) as (url, api):
        client = Client(url)
        with client.session() as s:
            for name, (body, kind) in cases.items():
                with pytest.raises(ClientError) as e:
                    s._conn.request("POST", f"/v1/sessions/{s.id}/frames", body, kind)
                assert e.value.status == 400, (name, e.value)
            assert "more than the limit" in str(pytest.raises(ClientError, s._conn.request, "POST",
                                                              f"/v1/sessions/{s.id}/frames", big_png(5000, 5000),
                                                              "image/png").value)
            assert s.send(paths[0])["frame"] == 0  # the session still starts at its first frame
        assert 500 not in api.metrics.requests


def test_a_map_without_describe_provenance_refuses_images_with_415(serve_service, image_service):
    _, paths = image_service
    assert serve_service.describer is None
    with serving(serve_service) as (url, _), Client(url).session() as s:
        with pytest.raises(ClientError) as e:
            s.send(paths[0])
        assert e.value.status == 415 and "does not describe images" in e.value.message


def test_a_pca_datasets_images_are_reduced_by_its_pca(tmp_path):
    """A map reduced by ``--pca D`` serves images: described, then projected by ``<DATASET>.pca.npz``."""
    from seqnet.data.io import load_dataset, save_dataset
    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.describe import DescribeConfig, make_describer
    from seqnet.describe.stage import describe_provenance
    from seqnet.localize.config import LocalizeConfig
    from seqnet.pipelines.pca import reduce_dataset, save_reduced
    from seqnet.serve.service import load_service

    folder = image_folder(tmp_path / "imgs", n=30, seed=3)
    conf = DescribeConfig(method="pixels", patch=8, size="native")
    paths = sorted(folder.iterdir(), key=lambda p: int(p.stem[1:]))
    ref, names = make_describer(conf).describe(paths)
    t = Traverse(ref, np.c_[np.arange(30) * 2.0, np.zeros(30)], names=names,
                 provenance=describe_provenance(conf, None, ref))
    save_dataset(Dataset(t, t, 3.0, splits={"train": {"reference": (0, 20), "query": (0, 20)}}), tmp_path / "raw")
    save_reduced(*reduce_dataset(load_dataset(tmp_path / "raw"), 8), tmp_path / "ds")
    service = load_service(LocalizeConfig(method="raw+seqmatch", seq_len=3, device="cpu"), tmp_path / "ds")
    assert service.describer is not None, service.no_images
    out = service.describer(service.describer.load(paths[:4]))
    np.testing.assert_allclose(out, np.asarray(load_dataset(tmp_path / "ds").query.descriptors[:4]), atol=1e-5)
