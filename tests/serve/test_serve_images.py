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
    t = Traverse(ref, pos, names=names, provenance=describe_provenance(conf, None, ref, (32, 16)))  # as recorded
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


def _post(s, body, kind):
    """``(status, message)`` of one frame posted to session ``s`` (200 and the answer's frame when accepted)."""
    try:
        return 200, s._conn.request("POST", f"/v1/sessions/{s.id}/frames", body, kind)[1]["frame"]
    except ClientError as e:
        return e.status, e.message


def _png(path, size=None, fmt="PNG", **kw):
    from PIL import Image

    im = Image.open(path).convert("RGB")
    buf = io.BytesIO()
    (im.resize(size) if size else im).save(buf, fmt, **kw)
    return buf.getvalue()


def test_every_image_is_held_to_the_maps_image_size_whatever_was_sent_before(image_service):
    """The map's images are 32x16 (native size): a portrait 16x32 image or one of another size is refused with
    both sizes and what to send, in every session, before and after good images from any session (the check is
    per image, not made once for the server), and a refused image leaves its session's window as it was."""
    service, paths = image_service
    portrait, big = _png(paths[0], (16, 32)), _png(paths[0], (64, 32))
    turned = ("the image is 16x32, portrait, and this map's images are 32x16, landscape (described at their own "
              "size): a turned camera? send frames as the map's were taken, 32x16")
    with serving(service) as (url, api):
        client = Client(url)
        with client.session() as a, client.session() as b, client.session() as c:
            assert _post(a, portrait, "image/png") == (400, turned)
            assert _post(b, _png(paths[0]), "image/png") == (200, 0)
            assert _post(c, portrait, "image/png") == (400, turned)
            assert _post(a, portrait, "image/png") == (400, turned)
            assert _post(b, big, "image/png") == (400, "the image is 64x32 and this map's images are 32x16 "
                                                      "(described at their own size): resize frames to 32x16 "
                                                      "before sending")
            assert _post(a, _png(paths[1]), "image/png") == (200, 0) and _post(b, _png(paths[1]), "image/png") \
                == (200, 1)
        assert 500 not in api.metrics.requests


def test_image_refusals_say_what_the_body_is_for_an_http_client(image_service, caplog):
    """A PNG labelled image/jpeg is named a PNG (with the type to send), an empty body empty, a GIF a format the
    server does not read; a damaged image is said damaged; no message names a command-line option. WEBP (which
    seqnet reads from files) is accepted: a lossless one answers as its PNG does, silently."""
    service, paths = image_service
    png = _png(paths[0])
    with serving(service) as (url, api):
        with Client(url).session() as s, Client(url).session() as t:
            said = {name: _post(s, body, kind) for name, (body, kind) in {
                "png as jpeg": (png, "image/jpeg"), "empty": (b"", "image/png"),
                "gif": (_png(paths[0], fmt="GIF"), "image/png"), "truncated": (png[: len(png) // 2], "image/png"),
                "text": (b"hello there", "image/png")}.items()}
            assert said["png as jpeg"] == (400, "the body is a PNG image but its Content-Type says image/jpeg: send "
                                                "it as image/png")
            assert said["empty"][1].startswith("the body is empty: send one image (image/png, image/jpeg, "
                                               "image/webp)")
            assert said["gif"][1].startswith("the body is a GIF image, which this server does not read")
            assert said["truncated"][1].startswith("cannot decode the body as PNG (")
            assert said["text"][1].startswith("the body is not a PNG image (Content-Type image/png) nor an image")
            assert all(status == 400 and "--" not in msg for status, msg in said.values()), said
            caplog.clear()
            for p in paths[:4]:
                a = s._conn.request("POST", f"/v1/sessions/{s.id}/frames", _png(p, fmt="WEBP", lossless=True),
                                    "image/webp")[1]
                b = t.send(p)
                assert {k: v for k, v in a.items() if k != "latency_ms"} == \
                       {k: v for k, v in b.items() if k != "latency_ms"}
            assert not [r for r in caplog.records if r.levelno >= 30], caplog.text
        assert 500 not in api.metrics.requests


def test_an_image_of_another_d_is_refused_per_image_on_a_map_that_records_no_image_size(tmp_path):
    """A map whose provenance records no image size (made before it was recorded): each image giving another D
    is refused with its size and both D (not the localiser's bare 'dimension mismatch'), after good ones too."""
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse
    from seqnet.describe import DescribeConfig, make_describer
    from seqnet.describe.stage import describe_provenance
    from seqnet.localize.config import LocalizeConfig
    from seqnet.serve.service import load_service

    conf = DescribeConfig(method="pixels", patch=8, size="native")
    paths = sorted(image_folder(tmp_path / "imgs", n=12, seed=4).iterdir(), key=lambda p: int(p.stem[1:]))
    ref, names = make_describer(conf).describe(paths)
    t = Traverse(ref, np.c_[np.arange(12) * 2.0, np.zeros(12)], names=names,
                 provenance=describe_provenance(conf, None, ref))
    save_dataset(Dataset(t, t, 3.0), tmp_path / "map")
    service = load_service(LocalizeConfig(method="raw+seqmatch", seq_len=3, device="cpu"), tmp_path / "map")
    want = ("the image is 64x32 and gives D=2048, this map's descriptors D=512 (described at their own size): send "
            "frames of the size of the map's reference images")
    with serving(service) as (url, _), Client(url).session() as s:
        assert _post(s, _png(paths[0], (64, 32)), "image/png") == (400, want)
        assert _post(s, _png(paths[0]), "image/png") == (200, 0)
        assert _post(s, _png(paths[1], (64, 32)), "image/png") == (400, want)
        assert _post(s, _png(paths[1]), "image/png") == (200, 1)
