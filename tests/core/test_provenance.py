"""Provenance: descriptors and models made differently are refused with one line naming both settings."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.core.provenance import ProvenanceError, check_same, described_text, differences, make, sidecar
from seqnet.data.readers import read_provenance
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.sequence.checkpoints import load_model, save_checkpoint
from seqnet.sequence.model import SeqNet


def test_make_and_differences():
    a = make("describe", {"method": "gem", "size": [160, 120]}, ["x.png", "y.png"], 64)
    b = make("describe", {"method": "gem", "size": [640, 320]}, ["y.png", "x.png"], 64)
    assert a["id"] != b["id"] and a["fit_images"] == b["fit_images"]  # fit images: order-independent
    assert differences(a, b) == ["size: [160, 120] vs [640, 320]"]
    with pytest.raises(ProvenanceError, match=r"size: \[160, 120\] vs \[640, 320\]; hint: describe both"):
        check_same(a, b, "the reference descriptors", "the query descriptors")
    check_same(a, b, "x", "y", allow=True)  # a warning only
    check_same(a, None, "x", "y")  # unknown provenance: accepted
    c = make("describe", {"method": "gem", "size": [160, 120]}, ["z.png"], 64)
    assert differences(a, c) == ["fitted state (PCA / NetVLAD clusters): fitted on different images"]


def test_unknown_provenance_against_a_known_one_is_a_warning_once_per_file(caplog):
    """Descriptors of unknown provenance held to known ones pass on their D alone: said at default verbosity
    (a warning with a hint), once per file; two unknown sides (files all from elsewhere) stay a debug note."""
    import logging

    a = make("describe", {"method": "pixels"}, None, 8)
    with caplog.at_level(logging.DEBUG, logger="seqnet"):
        for _ in range(3):
            check_same(a, None, "the map's descriptors", "the query descriptors q_once.npy")
        check_same(None, None, "the descriptors of r_both.npy", "the descriptors of q_both.npy")
    said = [(r.levelno, r.getMessage()) for r in caplog.records if "unknown" in r.getMessage()]
    warned = [m for lvl, m in said if lvl == logging.WARNING]
    assert len(warned) == 1 and warned[0].startswith("provenance of the query descriptors q_once.npy unknown: "
                                                     "only the descriptor dimension is checked against the map's")
    assert "hint: make them with `seqnet describe`" in warned[0] and ".provenance.json" in warned[0]
    assert [lvl for lvl, m in said if "r_both.npy" in m] == [logging.DEBUG]


@pytest.fixture
def two_folders(tmp_path):
    rng = np.random.default_rng(0)
    for side in ("ref", "qry"):
        (tmp_path / side).mkdir()
        for i in range(6):
            img = (rng.random((24, 48, 3)) * 255).astype(np.uint8)
            Image.fromarray(img).save(tmp_path / side / f"f{i:02d}.png")
    csv = "name,frame\n" + "".join(f"f{i:02d}.png,{i}\n" for i in range(6))
    (tmp_path / "pos.csv").write_text(csv)
    return tmp_path


def describe(root, side, out, *extra):
    assert cli_main(["-q", "describe", str(root / side), "--method", "pixels", "--out", str(out), *extra]) == 0


def test_from_csv_refuses_descriptors_described_differently(two_folders, capsys):
    root = two_folders
    describe(root, "ref", root / "ref.h5", "--resize", "32x16")
    describe(root, "qry", root / "qry.npy", "--resize", "48x24")
    assert read_provenance(root / "ref.h5")["settings"]["size"] == [32, 16] and sidecar(root / "qry.npy").is_file()
    argv = ["dataset", "from-csv", "--ref-csv", str(root / "pos.csv"), "--ref-desc", str(root / "ref.h5"),
            "--query-csv", str(root / "pos.csv"), "--query-desc", str(root / "qry.npy"), "--radius", "1",
            "--out", str(root / "ds")]
    capsys.readouterr()
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "size: [32, 16] vs [48, 24]" in err[0] and not (root / "ds").exists()
    describe(root, "qry", root / "qry2.h5", "--resize", "32x16")
    argv[argv.index(str(root / "qry.npy"))] = str(root / "qry2.h5")
    assert cli_main(argv) == 0
    meta = json.loads((root / "ds" / "dataset.json").read_text())
    assert meta["provenance"]["reference"]["id"] == meta["provenance"]["query"]["id"]


def test_views_on_one_side_show_the_default_and_hint_the_views_without_allow_mismatch():
    """A describe record leaves ``views`` out at its default: a mismatch shows it as ``["raw"]`` (not ``null``),
    the hint names the ``--views`` to give, and ``--allow-mismatch`` (which cannot compare two D) is not offered."""
    a = make("describe", {"method": "pixels", "views": ["raw", "equalize"]}, None, 4096)
    b = make("describe", {"method": "pixels"}, None, 2048)
    assert differences(a, b) == ['views: ["raw", "equalize"] vs ["raw"]', "D: 4096 vs 2048"]
    with pytest.raises(ProvenanceError) as e:
        check_same(a, b, "the reference descriptors", "the query descriptors")
    msg = str(e.value)
    assert "null" not in msg and "--allow-mismatch" not in msg
    assert msg.endswith("hint: make the query descriptors with --views raw,equalize as the reference descriptors "
                        "were, or both without --views")
    with pytest.raises(ProvenanceError, match=r"hint: make the query descriptors with --views raw,equalize"):
        check_same(b, a, "the query descriptors", "the reference descriptors")  # either side plain
    c = make("describe", {"method": "pixels", "views": ["equalize", "raw"]}, None, 4096)
    with pytest.raises(ProvenanceError, match=r"hint: make both with the same --views .*, or pass --allow-mismatch"):
        check_same(a, c, "x", "y")  # same D: --allow-mismatch may still help
    d = make("describe", {"method": "pixels", "patch": 4}, None, 2048)
    with pytest.raises(ProvenanceError, match=r"hint: describe both .*, or pass --allow-mismatch if you know"):
        check_same(b, d, "x", "y")
    e2 = make("describe", {"method": "pixels", "patch": 4}, None, 1024)
    with pytest.raises(ProvenanceError) as e:
        check_same(b, e2, "x", "y")
    assert "--allow-mismatch" not in str(e.value) and "D: 2048 vs 1024" in str(e.value)
    ext = make("external", {"format": "npy"}, None, 2048)  # not a describe record: nothing filled in
    assert differences(ext, make("external", {"format": "h5"}, None, 2048)) == ['format: "npy" vs "h5"']


def test_described_text_names_the_views_only_when_not_the_default():
    assert described_text(make("describe", {"method": "pixels"}, None, 2048)) == "pixels, D=2048"
    assert described_text(make("describe", {"method": "pixels", "views": ["raw"]}, None, 2048)) == "pixels, D=2048"
    two = make("describe", {"method": "netvlad", "views": ["raw", "equalize"]}, None, 14336)
    assert described_text(two) == "netvlad, views raw,equalize, D=14336"
    assert described_text(make("synthetic", {"places": 100}, None, 8)) == "D=8" and described_text(None) == ""


def test_allow_mismatch_cannot_compare_two_dimensions(tmp_path, capsys):
    """Why the hint leaves ``--allow-mismatch`` out when D differs: with it, the build fails on the dimensions."""
    q = np.random.default_rng(0).random((4, 8)).astype(np.float32)
    for stem, desc, settings in (("r", np.hstack([q, q]), {"method": "pixels", "views": ["raw", "equalize"]}),
                                 ("q", q, {"method": "pixels"})):
        np.save(tmp_path / f"{stem}.npy", desc)
        (tmp_path / f"{stem}.names.txt").write_text("".join(f"f{i}.png\n" for i in range(4)))
        sidecar(tmp_path / f"{stem}.npy").write_text(json.dumps(make("describe", settings, None, desc.shape[1])))
    (tmp_path / "pos.csv").write_text("name,frame\n" + "".join(f"f{i}.png,{i}\n" for i in range(4)))
    argv = ["dataset", "from-csv", "--ref-csv", str(tmp_path / "pos.csv"), "--ref-desc", str(tmp_path / "r.npy"),
            "--query-csv", str(tmp_path / "pos.csv"), "--query-desc", str(tmp_path / "q.npy"), "--radius", "1",
            "--out", str(tmp_path / "ds")]
    capsys.readouterr()
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert '["raw", "equalize"] vs ["raw"]' in err and "--views raw,equalize" in err and "--allow-mismatch" not in err
    assert cli_main([*argv, "--allow-mismatch"]) == 2
    assert "dimension mismatch" in capsys.readouterr().err


def test_model_on_foreign_descriptors_and_other_seq_len(tmp_path):
    ds = make_synthetic(places=150, dim=8, seed=0)
    other = make_synthetic(places=150, dim=8, seed=1)  # same D, another synthetic condition: other provenance
    model = SeqNet(8, 8, 5, 3)
    model.provenance = other.reference.provenance
    save_checkpoint(tmp_path / "m.pt", model)
    loaded = load_model(tmp_path / "m.pt")
    assert loaded.provenance == other.reference.provenance
    conf = EvalConfig(methods=("seqnet",), device="cpu")
    with pytest.raises(ProvenanceError, match="the descriptors the S_5 model was trained on and the descriptors of"):
        evaluate(ds.split("test"), conf, {"seqnet": loaded})
    evaluate(ds.split("test"), conf.replace(allow_mismatch=True), {"seqnet": loaded})
    loaded.provenance = ds.reference.provenance
    evaluate(ds.split("test"), conf, {"seqnet": loaded})
    ev = evaluate(ds.split("test"), conf.replace(seq_len=3), {"seqnet": loaded})  # any L >= w: no flag needed
    assert ev.results["config"]["seq_len"] == 3 and ev.results["config"]["model_seq_len"] == {"seqnet": 5}
    for allow in (False, True):  # L < w cannot run: refused even with --allow-mismatch
        with pytest.raises(ConfigError, match="L=2, shorter than its convolution width w=3"):
            evaluate(ds.split("test"), conf.replace(seq_len=2, allow_mismatch=allow), {"seqnet": loaded})


def test_training_records_the_provenance(tmp_path):
    from seqnet.train import TrainConfig, train

    ds = make_synthetic(places=200, dim=8, seed=0)
    train(ds, TrainConfig(epochs=1, seq_len=3, w=2, device="cpu"), tmp_path / "run")
    assert load_model(tmp_path / "run" / "best.pt").provenance == ds.reference.provenance


def test_image_size_is_checked_beside_the_id_not_in_it(caplog):
    import logging

    settings = {"method": "pixels", "size": "native", "crop_bottom": 0, "patch": 8}
    old = make("describe", settings, dim=2048)  # a record made before image sizes were recorded
    land, port = (make("describe", settings, dim=2048, image_size=s) for s in ((64, 32), (32, 64)))
    assert old["id"] == land["id"] == port["id"] == "e343f8688483ae77"  # existing maps keep matching
    check_same(old, port, "the map's descriptors", "the query descriptors")  # one side silent on its size: as before
    check_same(land, dict(land), "a", "b")
    with pytest.raises(ProvenanceError, match=r"made from 64x32 images and the query descriptors from 32x64 images "
                                              r"\(native size\).*--resize 64x32"):
        check_same(land, port, "the map's descriptors", "the query descriptors")
    caplog.set_level(logging.WARNING, logger="seqnet")
    check_same(land, port, "a", "b", allow=True)
    assert "going on as asked" in caplog.text


def test_a_cnn_descriptor_of_another_resolution_compares_a_rotated_one_does_not():
    """A pooled CNN descriptor at native size from a 1280x720 and a 1920x1080 camera: one D, comparable, accepted
    as before; portrait against landscape is refused; pixels of another grid are refused (above)."""
    settings = {"method": "netvlad", "size": "native", "crop_bottom": 0}
    hd, fhd, port = (make("describe", settings, dim=4096, image_size=s) for s in ((1280, 720), (1920, 1080),
                                                                                 (720, 1280)))
    check_same(hd, fhd, "the map's descriptors", "the query descriptors")
    with pytest.raises(ProvenanceError, match="made from 1280x720 images and the query descriptors from 720x1280"):
        check_same(hd, port, "the map's descriptors", "the query descriptors")


def test_describe_records_the_size_it_saw(tmp_path):
    from seqnet.describe import DescribeConfig
    from seqnet.describe.describer import make_describer
    from seqnet.describe.stage import describe_provenance

    for i in range(2):
        Image.fromarray(np.full((16, 40, 3), 40 * i, np.uint8)).save(tmp_path / f"{i}.png")
    d = make_describer(DescribeConfig(method="pixels", patch=0))
    desc, _ = d.describe(sorted(tmp_path.iterdir()))
    assert d.seen_size == (40, 16)
    assert describe_provenance(d.config, None, desc, d.seen_size)["image_size"] == [40, 16]
