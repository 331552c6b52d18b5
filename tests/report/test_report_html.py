"""The HTML report is one self-contained file: every image a data: URI, no external URL, no script,
every section present (eval --report on synthetic data; the gallery on the shared nordland64 data)."""

from __future__ import annotations

import base64
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_data

from seqnet.cli import main as cli_main
from seqnet.data.io import save_dataset
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.report.html import SECTIONS, ReportConfig, write_html_report

PNG = b"\x89PNG\r\n\x1a\n"


class _Collect(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


def assert_self_contained(path: Path, sections=SECTIONS) -> list[tuple[str, dict]]:
    """Parse the report: no external reference of any kind, images embedded as valid PNGs, each section."""
    text = path.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    p = _Collect()
    p.feed(text)
    tags = p.tags
    names = {t for t, _ in tags}
    assert not names & {"link", "iframe", "object", "embed", "base", "video", "audio", "source"}
    assert all(not attrs for t, attrs in tags if t == "script")  # only the inline sorting script: loads nothing
    assert [t for t, _ in tags].count("script") <= 1
    for tag, attrs in tags:
        for key in ("src", "srcset", "data", "poster", "action", "background"):
            value = attrs.get(key)
            if value is not None:
                assert key == "src" and value.startswith("data:image/png;base64,"), (tag, key, value[:60])
                assert base64.b64decode(value.split(",", 1)[1]).startswith(PNG)
        if "href" in attrs:
            assert attrs["href"].startswith("#"), attrs["href"]  # in-page anchors only
        assert "url(" not in (attrs.get("style") or "")
    assert text.count('src="') == sum(1 for t, a in tags if "src" in a)  # every src=" is an attribute we checked
    ids = [a.get("id") for t, a in tags if t == "section"]
    for s in sections:
        assert s in ids, (s, ids)
    assert "url(" not in text.split("<style>")[1].split("</style>")[0]
    return tags


def test_eval_report_is_self_contained(tmp_path, synth_dir, capsys):
    out = tmp_path / "ev"
    rc = cli_main(["eval", "--dataset", str(synth_dir), "--method", "single,raw+seqmatch,hvpr-delta:raw+seqmatch",
                   "--out", str(out), "--report"])
    assert rc == 0 and "report:" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [".seqnet-manifest.json", "pr_curve.png", "report.html",
                                                     "results.json"]  # the manifest: what seqnet wrote there
    tags = assert_self_contained(out / "report.html")
    assert sum(t == "img" for t, _ in tags) == 4  # Recall@K, PR, distance matrix, trajectory; no gallery, no pairs
    text = (out / "report.html").read_text()
    assert "No gallery" in text and "hvpr-delta:raw+seqmatch" in text and "PR AUC" in text


def test_eval_report_option_errors(tmp_path, synth_dir, capsys):
    base = ["eval", "--dataset", str(synth_dir), "--method", "single"]
    assert cli_main([*base, "--report"]) == 2 and "give --out DIR" in capsys.readouterr().err
    assert cli_main([*base, "--out", str(tmp_path / "a"), "--images-ref", str(tmp_path)]) == 2
    assert "add --report" in capsys.readouterr().err
    assert cli_main([*base, "--out", str(tmp_path / "b"), "--report", "--images-ref", str(tmp_path)]) == 2
    assert "both --images-query and --images-ref" in capsys.readouterr().err
    assert cli_main([*base, "--out", str(tmp_path / "c"), "--report", "--images-ref", str(tmp_path / "nope"),
                     "--images-query", str(tmp_path)]) == 2
    assert "is not a folder" in capsys.readouterr().err


def test_report_gallery_with_images(tmp_path):
    data = shared_data("nordland64")
    names = [f"images-{i:05d}.png" for i in range(210, 210 + 10 * 60, 10)]
    rng = np.random.default_rng(0)
    pos = np.arange(len(names), dtype=float)
    base = rng.standard_normal((len(names), 8)).astype(np.float32)
    ds = Dataset(Traverse(base, pos, names=names), Traverse(base + 0.8 * rng.standard_normal(base.shape).astype(
        np.float32), pos, names=names), radius=1.0)
    ev = evaluate(ds, EvalConfig(methods=("single", "raw+seqmatch"), seq_len=3, device="cpu"))
    conf = ReportConfig(title="t", gallery_size=5, query_images=str(data / "winter"), ref_images=str(data / "summer"))
    path = write_html_report(ev, ds, tmp_path / "r.html", conf)
    tags = assert_self_contained(path)
    text = path.read_text()
    examples = [a.get("class") for t, a in tags if t == "div" and "ex" in (a.get("class") or "")]
    assert 1 <= len(examples) <= 5 and sum(t == "img" for t, _ in tags) == 3 + len(examples)
    if "ex bad" in examples:  # failures first
        assert examples[0] == "ex bad"
    assert "Method <b>raw+seqmatch</b>" in text  # the best R@1 by default


def test_report_sections_in_saved_dataset_eval(tmp_path, synth_dataset):
    """``seqnet.eval.evaluate.main`` with a ReportConfig writes the report beside results.json."""
    from seqnet.eval.evaluate import main

    d = save_dataset(synth_dataset, tmp_path / "ds")
    path = main(EvalConfig(methods=("single", "smoothing")), d, tmp_path / "o", report=ReportConfig(title="x"))
    assert json.loads(Path(path).read_text())["methods"]["single"]["queries"] > 0
    assert_self_contained(tmp_path / "o" / "report.html")


@pytest.mark.parametrize("bad", [{"k_max": 0}, {"gallery_method": "nope"}, {"matrix_side": -1}])
def test_report_config_validates(bad):
    from seqnet.core.errors import ConfigError

    with pytest.raises(ConfigError):
        ReportConfig(**bad)


@pytest.mark.filterwarnings("ignore::PIL.Image.DecompressionBombWarning")
def test_gallery_leaves_out_images_it_must_not_decode(tmp_path):
    """A decompression bomb or a FIFO among the gallery's frames leaves that example out (no traceback,
    no hang): the gallery reads through the describers' reader."""
    import os

    from PIL import Image

    from seqnet.report.figures import GalleryItem, gallery_png

    Image.new("RGB", (8, 4)).save(tmp_path / "ok.png")
    Image.new("1", (12000, 12000)).save(tmp_path / "bomb.png")  # 144 M pixels declared in a tiny file
    os.mkfifo(tmp_path / "fifo.png")
    good = GalleryItem(0, ["ok.png"], ["ok.png"], True, 0.5)
    assert gallery_png(good, tmp_path, tmp_path).startswith(b"\x89PNG")
    for bad in ("bomb.png", "fifo.png"):
        assert gallery_png(GalleryItem(0, ["ok.png"], [bad], True, 0.5), tmp_path, tmp_path) is None


def _png(path, value):
    from PIL import Image

    Image.fromarray(np.full((4, 8, 3), value, np.uint8)).save(path)


def test_gallery_never_reads_outside_its_image_folders(tmp_path, monkeypatch):
    """A name from names.txt (untrusted) that is absolute, holds '..' or leads through a link out of the images'
    folder is never opened: the example is left out with a note."""
    import seqnet.report.figures as figures
    from seqnet.report.figures import GalleryItem, gallery_png

    imgs, secret = tmp_path / "imgs", tmp_path / "secret.png"
    imgs.mkdir()
    _png(imgs / "ok.png", 10)
    _png(secret, 200)
    (imgs / "link.png").symlink_to(secret)
    (imgs / "up").symlink_to(tmp_path)
    opened = []
    real = figures.open_input
    monkeypatch.setattr(figures, "open_input", lambda p, *a, **k: opened.append(str(p)) or real(p, *a, **k))
    assert gallery_png(GalleryItem(0, ["ok.png"], ["ok.png"], True, 0.5), imgs, imgs).startswith(PNG)
    for bad in (str(secret), "../secret.png", "link.png", "up/secret.png", "sub/../../secret.png"):
        notes = []
        assert gallery_png(GalleryItem(0, ["ok.png"], [bad], True, 0.5), imgs, imgs, notes=notes) is None, bad
        assert len(notes) == 1 and "leads outside" in notes[0], notes
    assert not [p for p in opened if "secret" in p or "link" in p or "up/" in p], opened

    monkeypatch.setattr(figures, "find_inside", lambda root, rel, *a: root / rel)  # a link swapped in after the check
    notes = []
    assert gallery_png(GalleryItem(0, ["ok.png"], ["link.png"], True, 0.5), imgs, imgs, notes=notes) is None
    assert "leads outside" in notes[0]


def test_eval_report_gallery_with_hostile_names(tmp_path, capsys):
    """``eval --report`` with image folders: reference names leading out of their folder are left out of the
    gallery with a note (never read), the report is still written whole."""
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=120, dim=16, seed=2)
    (tmp_path / "q").mkdir()
    (tmp_path / "r").mkdir()
    _png(tmp_path / "secret.png", 200)
    names = list(ds.reference.names)
    for i, n in enumerate(names):
        names[i] = f"../secret{i}.png" if i % 2 else n
        _png(tmp_path / "r" / n, 30)
    ds.reference.names = names
    for n in ds.query.names:
        _png(tmp_path / "q" / n, 60)
    save_dataset(ds, tmp_path / "ds")
    out = tmp_path / "ev"
    assert cli_main(["eval", "--dataset", str(tmp_path / "ds"), "--method", "single", "--out", str(out), "--report",
                     "--images-query", str(tmp_path / "q"), "--images-ref", str(tmp_path / "r")]) == 0
    text = (out / "report.html").read_text()
    assert "pictures left out: gallery image name" in text and "leads outside" in text
    assert_self_contained(out / "report.html")


def test_choices_section_says_what_val_chose_and_shows_each_grid():
    """The benchmark's and ``seqnet eval``'s ``"selection"``: one line per choice (escaped), every grid scored, and
    nothing when nothing was chosen."""
    from seqnet.report.notes import choices_section

    sel = {"descriptor": {"chosen": "netvlad", "reason": "descriptor netvlad chosen on val <b>",
                          "scores": {"pixels": {"raw+seqmatch": 0.58, "queries": 266},
                                     "netvlad": {"raw+seqmatch": 0.9}}},
           "hvpr": [{"method": "hvpr-fused", "reason": "K 200, λ 0.25", "grid": [
               {"top_k": 50, "fuse_weight": 0.25, "recall@1": 0.989}, {"top_k": 200, "fuse_weight": 2.0,
                                                                      "recall@1": 0.981}]}]}
    (sec,) = choices_section({"selection": sel})
    assert sec.id == "choices" and "chosen on val &lt;b&gt;" in sec.body
    assert "K 200, λ 0.25" in sec.body and "no other split was read" in sec.body
    assert sec.body.count("<details>") == 2 and "0.989" in sec.body and "0.25" in sec.body and "pixels" in sec.body
    (why,) = choices_section({"selection": {"hvpr": [], "not_chosen": "HVPR settings not chosen: no val query"}})
    assert "no val query" in why.body and "no other split" not in why.body
    (few,) = choices_section({"selection": {**sel, "warning": "HVPR settings chosen on 3 val queries <i>"}})
    assert "chosen on 3 val queries &lt;i&gt;" in few.body and "K 200, λ 0.25" in few.body
    assert choices_section({}) == [] and choices_section({"selection": {"hvpr": []}}) == []


def test_report_has_the_choices_of_its_results(tmp_path, synth_dataset):
    ev = evaluate(synth_dataset, EvalConfig(methods=("single",)))
    ev.results["selection"] = {"hvpr": [{"method": "hvpr", "reason": "hvpr: K 50 chosen on val", "grid": []}]}
    write_html_report(ev, synth_dataset, tmp_path / "r.html", ReportConfig(title="x"))
    text = (tmp_path / "r.html").read_text()
    assert 'id="choices"' in text and "hvpr: K 50 chosen on val" in text
    assert_self_contained(tmp_path / "r.html")


def test_the_results_table_wraps_and_scrolls_in_its_own_box():
    """A wide results table (long method names, the note column) wraps its text cells and, in a window narrower
    than it, scrolls sideways inside its box instead of running off the page (checked by eye at 1200 and 800 px)."""
    from types import SimpleNamespace

    from seqnet.report.html import CSS, results_section

    res = {"methods": {"hvpr-fused:s1+seqmatch-rev": {"recall@1": 0.5, "queries": 10}}, "config": {"ks": [1]}}
    body = results_section(SimpleNamespace(results=res)).body
    assert body.startswith('<div class="wide"><table class="sortable">') and "</table></div>" in body
    assert ".wide{overflow-x:auto" in CSS
    assert "#results td:last-child,#results th:last-child{text-align:left;white-space:normal" in CSS
    assert "#results td:nth-child(2){white-space:normal" in CSS  # the family column wraps too


def test_the_results_table_says_what_its_columns_mean():
    """R@K, PR AUC and R@100P are said under the table (the page left them unexplained)."""
    from types import SimpleNamespace

    from seqnet.report.html import results_section

    res = {"methods": {"single": {"recall@1": 0.5, "queries": 10}}, "config": {"ks": [1]}}
    body = results_section(SimpleNamespace(results=res)).body
    for said in ("R@K: the share of queries", "PR AUC: the area under the precision–recall curve",
                 "R@100P: the largest share", "(recall at 100 % precision)", "Click a column's heading"):
        assert said in body, said


def test_the_summary_names_the_descriptors_evaluated(tmp_path, synth_dataset):
    """Which descriptors were compared (method, views, PCA, D, provenance id) is in the results and the Summary."""
    import dataclasses

    from seqnet.report.html import summary_section

    settings = {"method": "pixels", "size": "native", "patch": 8, "views": ["raw", "equalize"], "dim": 8,
                "pca_on": "train"}
    prov = {"kind": "describe", "settings": settings, "dim": 16, "id": "6d180b12166d4a0d"}
    ds = dataclasses.replace(synth_dataset, reference=dataclasses.replace(synth_dataset.reference, provenance=prov),
                             query=dataclasses.replace(synth_dataset.query, provenance=prov))
    ev = evaluate(ds, EvalConfig(methods=("single",)))
    body = summary_section(ev, ReportConfig()).body
    assert "<td>descriptors</td><td>pixels, views raw,equalize, PCA to 8, D=16 (provenance 6d180b12166d4a0d)</td>" \
        in body, body
    q = dataclasses.replace(ds.query, provenance=None)
    ev = evaluate(dataclasses.replace(ds, query=q), EvalConfig(methods=("single",), allow_mismatch=True))
    body = summary_section(ev, ReportConfig()).body
    assert ("reference: pixels, views raw,equalize, PCA to 8, D=16 (provenance 6d180b12166d4a0d); query: unknown "
            "method, D=16 (provenance unknown)") in body
    ev.results.pop("descriptors")  # a route that records none (a matrix, a map): no row
    assert "descriptors" not in summary_section(ev, ReportConfig()).body
