"""``eval --report --images-query/--images-ref`` against the sources dataset.json records: the two folders (or
videos) given the wrong way round are said, on stderr and in the report."""

from __future__ import annotations

import numpy as np
from PIL import Image

from seqnet.cli import main as cli_main
from seqnet.data.io import save_dataset
from seqnet.report.sources import recorded_sources, swapped_sources


def _folders(tmp_path):
    for side in ("ref", "qry"):
        (tmp_path / side).mkdir()
    return str(tmp_path / "ref"), str(tmp_path / "qry")


def test_swapped_folders_and_videos_are_said_the_right_order_is_not(tmp_path):
    ref, qry = _folders(tmp_path)
    images = {"images": {"reference": ref, "query": qry}}
    assert swapped_sources(images, qry, ref) is None
    said = swapped_sources(images, ref, qry)
    assert said == (f"--images-query {ref} is the dataset's reference source and --images-ref {qry} is the dataset's "
                    "query source (as dataset.json records it): the report's pictures would show the wrong traverse "
                    "beside each example; hint: swap them")
    one = swapped_sources(images, ref, str(tmp_path))  # only the query flag names the other side's folder
    assert one.startswith(f"--images-query {ref} is the dataset's reference source (as dataset.json")
    assert one.endswith(f"hint: --images-query {qry}; --images-ref {ref}")
    (tmp_path / "r.mp4").write_bytes(b"x")
    (tmp_path / "q.mp4").write_bytes(b"y")
    videos = {"videos": {"reference": {"path": str(tmp_path / "r.mp4")}, "query": {"path": str(tmp_path / "q.mp4")}}}
    assert recorded_sources(videos) == {"reference": str(tmp_path / "r.mp4"), "query": str(tmp_path / "q.mp4")}
    assert "--images-query" in swapped_sources(videos, str(tmp_path / "r.mp4"), str(tmp_path / "q.mp4"))
    assert swapped_sources(videos, str(tmp_path / "q.mp4"), str(tmp_path / "r.mp4")) is None
    assert swapped_sources({}, ref, qry) is None  # nothing recorded: nothing to say
    same = {"images": {"reference": ref, "query": ref}}  # one folder for both sides: not a swap
    assert swapped_sources(same, ref, ref) is None


def test_eval_report_with_swapped_folders_warns_and_says_it_in_the_report(tmp_path, capsys):
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=120, dim=16, seed=2)
    ref, qry = _folders(tmp_path)
    for folder, names in ((ref, ds.reference.names), (qry, ds.query.names)):
        for n in names:
            Image.fromarray(np.full((8, 16), 90, np.uint8)).save(f"{folder}/{n}")
    ds.extra = {**ds.extra, "images": {"reference": ref, "query": qry}}
    save_dataset(ds, tmp_path / "ds")
    base = ["eval", "--dataset", str(tmp_path / "ds"), "--method", "single", "--report"]
    assert cli_main([*base, "--out", str(tmp_path / "ok"), "--images-query", qry, "--images-ref", ref]) == 0
    assert "source" not in capsys.readouterr().err
    assert "Picture sources" not in (tmp_path / "ok" / "report.html").read_text()
    assert cli_main([*base, "--out", str(tmp_path / "bad"), "--images-query", ref, "--images-ref", qry]) == 0
    assert f"--images-query {ref} is the dataset's reference source" in capsys.readouterr().err
    text = (tmp_path / "bad" / "report.html").read_text()
    assert "Picture sources" in text and "the report&#x27;s pictures would show the wrong traverse" in text


def test_an_example_names_its_images_within_the_folders(tmp_path):
    """Session 54, a dataset from list files of absolute paths: each example's caption read 'query
    /work/shared/data/nordland64/winter/images-12420.png → /work/shared/data/nordland64/summer/images-12420.png',
    five lines a cell; inside the given folders the names are read within them (a name elsewhere stays whole)."""
    from seqnet.report.figures import GalleryItem
    from seqnet.report.html import gallery_cell

    winter, summer = tmp_path / "winter", tmp_path / "summer"
    item = GalleryItem(0, [str(winter / "images-12420.png")], [str(summer / "sub" / "images-12420.png")], True, 0.11)
    text = gallery_cell(item, None, folders=(str(winter), str(summer)))
    assert "correct: query images-12420.png → sub/images-12420.png (confidence 0.11)" in text, text
    assert str(tmp_path) not in text
    elsewhere = GalleryItem(0, ["images-12420.png"], ["/elsewhere/x.png"], False, 0.5)
    assert "query images-12420.png → /elsewhere/x.png" in gallery_cell(elsewhere, None, folders=(str(winter),
                                                                                                  str(summer)))
