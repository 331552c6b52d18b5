"""Your own data end to end (docs/own_data.md): two image folders + ground truth → dataset → eval.

Tiny generated route: every place has its own texture; the query traverse sees it with another
brightness and noise, at half the reference frame rate (reference frames 2i and 2i+1 show query
frame i's place), so the ground truth is many-to-one.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main
from seqnet.data.io import load_dataset


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    root = tmp_path_factory.mktemp("own")
    rng = np.random.default_rng(0)
    places = rng.random((40, 16, 32, 3))
    (root / "ref").mkdir()
    (root / "qry").mkdir()
    for j in range(80):  # reference: two frames per place
        img = places[j // 2] * 0.9 + 0.1 * rng.random((16, 32, 3))
        Image.fromarray((img * 255).astype(np.uint8)).save(root / "ref" / f"@{500000 + 5 * j}@{6000000}@r{j:03d}.png")
    for i in range(40):
        img = np.clip(places[i] * 0.6 + 0.2 + 0.15 * rng.random((16, 32, 3)), 0, 1)
        name = f"@{500000 + 10 * i + 2}@{6000000}@q{i:03d}.png"
        Image.fromarray((img * 255).astype(np.uint8)).save(root / "qry" / name)
    (root / "positives.json").write_text(json.dumps([[2 * i, 2 * i + 1] for i in range(40)]))
    ref_names = sorted(p.name for p in (root / "ref").iterdir())
    qry_names = sorted(p.name for p in (root / "qry").iterdir())
    (root / "ref.csv").write_text("image,frame\n" + "".join(f"{n},{j / 2}\n" for j, n in enumerate(ref_names)))
    (root / "qry.csv").write_text("image,frame\n" + "".join(f"{n},{i}\n" for i, n in enumerate(qry_names)))
    return root


def build(route, out, *truth, capsys=None):
    argv = ["-q", "dataset", "from-images", str(route / "ref"), str(route / "qry"), "--method", "pixels",
            "--patch", "0", "--out", str(out), *truth]
    return main(argv)


@pytest.mark.parametrize("truth, radius", [
    (["--positives", "positives.json"], "1"),
    (["--ref-csv", "ref.csv", "--query-csv", "qry.csv"], "0.5"),
    (["--utm-names"], "6"),
])
def test_images_to_results(route, tmp_path, capsys, truth, radius):
    truth = [str(route / t) if t.endswith((".json", ".csv")) else t for t in truth]
    assert build(route, tmp_path / "ds", *truth, "--radius", radius) == 0
    ds = load_dataset(tmp_path / "ds")
    assert len(ds.reference) == 80 and len(ds.query) == 40
    assert ds.reference.provenance["id"] == ds.query.provenance["id"]
    if "--positives" in truth:
        assert ds.positives.of(3).tolist() == [6, 7]
    capsys.readouterr()
    argv = ["eval", "--dataset", str(tmp_path / "ds"), "--method", "single,raw+seqmatch", "--seq-len", "3",
            "--per-query", str(tmp_path / "pq.jsonl"), "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "single" in out and "queries evaluated" in out
    header = out.splitlines()[0]
    assert ("explicit positives" in header) == ("--positives" in truth) and ("radius" in header) != (
        "--positives" in truth)  # R@K with explicit positives is not "within radius 1"
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["methods"]["single"]["recall@1"] >= 0.5  # 40 places: chance is 1/40
    rows = [json.loads(line) for line in (tmp_path / "pq.jsonl").read_text().splitlines()]
    assert {r["method"] for r in rows} == {"single", "raw+seqmatch"} and rows[0]["query_name"].endswith(".png")


def test_frame_aligned_and_errors(route, tmp_path, capsys):
    # frame-aligned: query i <-> reference i cannot hold for 80 reference and 40 query frames: refused
    assert build(route, tmp_path / "fa", "--frame-aligned", "--radius", "2") == 2
    assert "reference has 80 images and the query 40" in capsys.readouterr().err and not (tmp_path / "fa").exists()
    rc = build(route, tmp_path / "x", "--ref-csv", str(route / "ref.csv"), "--radius", "1")
    assert rc == 2 and "--ref-csv needs --query-csv" in capsys.readouterr().err
    rc = build(route, tmp_path / "x", "--positives", str(route / "ref.csv"), "--radius", "1")
    assert rc == 2 and not (tmp_path / "x").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    rc = build(route, tmp_path / "mine", "--positives", str(route / "positives.json"), "--overwrite")
    err = capsys.readouterr().err
    assert rc == 2 and "seqnet did not write" in err and (tmp_path / "mine" / "notes.txt").read_text() == "mine"


def test_one_fit_for_both_traverses(route, tmp_path):
    """A PCA is fitted once (on the reference) and applied to both: their provenance is one."""
    assert build(route, tmp_path / "pca", "--positives", str(route / "positives.json"), "--dim", "8") == 0
    ds = load_dataset(tmp_path / "pca")
    assert ds.reference.dim == ds.query.dim == 8
    assert ds.reference.provenance == ds.query.provenance and ds.reference.provenance["fit_images"]


@pytest.mark.parametrize(("zones", "error"), [(("32V", "32V"), None), (("32V", "?"), None),
                                              (("32V", "33V"), "UTM zone 32V, query positions in 33V"),
                                              (("UTM zone 32V", "UTM zone ?"), None),  # a log's frame, zone unknown
                                              (("UTM zone 32V", "UTM zone 33V"), r"UTM zone 32V, query positions in "
                                                                                 r"33V; positions in two zones"),
                                              (("odometry frame 'odom'", "odometry frame 'map'"),
                                               r"in odometry frame 'odom', query positions in odometry frame 'map'; "
                                               r"positions in two frames are not comparable$"),
                                              (("32V", None), "are metres in 32V and the query positions easting"),
                                              ((None, None), None)])
def test_both_sides_positions_are_in_one_frame(monkeypatch, zones, error):
    """Metres compare only in one UTM zone: the zones of the two sides are checked as every other reader checks
    them (``data.gps.check_zones``: an unknown zone is let through), a zone on one side only is refused."""
    from seqnet.core.errors import SeqnetError
    from seqnet.pipelines import from_images, ground_truth

    sides = iter(zones)
    monkeypatch.setitem(ground_truth.GROUND_TRUTH_SOURCES, "csv",
                        lambda *a: (np.zeros((2, 2)), None, "metres", next(sides)))
    conf = from_images.FromImagesConfig(ground_truth="csv")
    if error is None:
        ground_truth.both_positions(conf, (None, None), ("r", "q"), (None, None))
    else:
        with pytest.raises(SeqnetError, match=error):
            ground_truth.both_positions(conf, (None, None), ("r", "q"), (None, None))


def test_a_dataset_described_into_spill_files_equals_one_described_in_memory(route, tmp_path, monkeypatch):
    assert build(route, tmp_path / "held", "--positives", str(route / "positives.json")) == 0
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")  # both traverses' descriptors go to spill files, written in blocks
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "0")
    assert build(route, tmp_path / "spilled", "--positives", str(route / "positives.json")) == 0
    for side in ("reference", "query"):
        a, b = (tmp_path / d / side / "descriptors.npy" for d in ("held", "spilled"))
        assert a.read_bytes() == b.read_bytes(), side
    assert load_dataset(tmp_path / "spilled").reference.descriptors.shape == (80, 16 * 32)


def test_pca_is_fitted_on_the_train_split_only(route, tmp_path, capsys):
    splits = ["--split", "train=0:40,0:20", "--split", "val=40:60,20:30", "--split", "test=60:80,30:40"]
    assert build(route, tmp_path / "p", "--utm-names", "--radius", "6", *splits, "--pca", "8") == 0
    assert "fitted on the train split only" in capsys.readouterr().out
    ds = load_dataset(tmp_path / "p")
    assert ds.query.dim == 8 and ds.extra["pca"]["fit_ranges"] == {"reference": [0, 40], "query": [0, 20]}
    assert (tmp_path / "p.pca.npz").is_file() and ds.reference.provenance["settings"]["dim"] == 8
    assert build(route, tmp_path / "q", "--utm-names", "--radius", "6", "--pca", "8") == 2
    assert "train split only" in capsys.readouterr().err and not (tmp_path / "q").exists()


def test_without_method_the_descriptor_is_chosen_on_val(route, tmp_path, capsys, monkeypatch):
    """No --method: each candidate that can run describes only the val images (never a test image), the model-free
    proxy picks one, the dataset is described with it and the choice is recorded and said; without a val split it is
    one line asking for one."""
    from seqnet.cli.dataset_cmd import images as images_cmd
    from seqnet.pipelines import descriptor_choice, from_images

    monkeypatch.setattr(images_cmd, "CANDIDATES", ("pixels", "gmp"))
    monkeypatch.setattr(descriptor_choice, "runnable", lambda d: None if d.method == "pixels" else "not installed")
    described = []
    real = from_images.make_describer

    def spy(*a, **k):
        d = real(*a, **k)
        inner = d.describe
        d.describe = lambda paths, names, **kw: (described.append(list(names)), inner(paths, names, **kw))[1]
        return d

    monkeypatch.setattr(from_images, "make_describer", spy)
    base = ["-q", "dataset", "from-images", str(route / "ref"), str(route / "qry"), "--patch", "0",
            "--positives", str(route / "positives.json")]
    assert main([*base, "--out", str(tmp_path / "x")]) == 2
    assert "needs a val split" in capsys.readouterr().err and not (tmp_path / "x").exists()
    assert main([*base, "--describer", "pkg.mod:make", "--out", str(tmp_path / "x")]) == 2
    assert "--describer needs --method plugin" in capsys.readouterr().err and not (tmp_path / "x").exists()
    splits = ["--split", "val=0:80,0:20", "--split", "test=0:80,20:40"]
    assert main([*base, *splits, "--out", str(tmp_path / "ds")]) == 0
    capsys.readouterr()
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    choice = meta["descriptor_choice"]
    assert choice["chosen"] == "pixels" and choice["skipped"] == {"gmp": "not installed"}
    assert choice["scores"]["pixels"]["queries"] == 16 and 0 <= choice["scores"]["pixels"]["raw+seqmatch"] <= 1
    assert choice["reason"].startswith("descriptor pixels chosen on val queries 0:20 against reference 0:80 (16 ")
    assert "not tried: gmp" in choice["reason"]
    qry_names = sorted(p.name for p in (route / "qry").iterdir())
    assert described[1] == qry_names[:20]  # the choice: the val queries only (after the val reference)
    assert described[-1] == qry_names  # then the dataset: every query
    assert load_dataset(tmp_path / "ds").query.provenance["settings"]["method"] == "pixels"


def test_choose_on_val_ranks_by_the_proxy_then_single_then_order():
    from seqnet.describe import DescribeConfig
    from seqnet.pipelines.descriptor_choice import choose_on_val

    got = {"pixels": (0.5, 0.2), "netvlad": (0.9, 0.3), "gem": (0.9, 0.4), "gmp": (0.9, 0.4)}
    cands = {n: DescribeConfig(method=n) for n in got}
    score = lambda d: {"raw+seqmatch": got[d.method][0], "single": got[d.method][1], "queries": 7}  # noqa: E731
    dconf, record = choose_on_val(cands, score, "val")
    assert dconf.method == "gem" and record["chosen"] == "gem"  # the tie-break: single, then the first listed
    assert "against pixels 0.500, netvlad 0.900, gmp 0.900" in record["reason"]


def test_the_choice_fits_no_test_image(route, tmp_path, monkeypatch):
    """A candidate that fits a state (here pixels with a PCA, --dim) is fitted, for the val proxy, only on its
    fitting images of the train and val splits: with --fit-on both, the test queries are left out."""
    from seqnet.cli.dataset_cmd import images as images_cmd
    from seqnet.pipelines import descriptor_choice, from_images

    monkeypatch.setattr(images_cmd, "CANDIDATES", ("pixels", "gmp"))
    monkeypatch.setattr(descriptor_choice, "runnable", lambda d: None if d.method == "pixels" else "not installed")
    fits = []
    real = from_images.make_describer
    monkeypatch.setattr(from_images, "make_describer", lambda conf, fit, *a, **k: (
        fits.append([str(p) for p in fit] if conf.needs_fit else None), real(conf, fit, *a, **k))[1])
    argv = ["-q", "dataset", "from-images", str(route / "ref"), str(route / "qry"), "--patch", "0", "--dim", "4",
            "--fit-on", "both", "--positives", str(route / "positives.json"), "--split", "train=0:80,0:10",
            "--split", "val=0:80,10:20", "--split", "test=0:80,20:40", "--out", str(tmp_path / "ds")]
    assert main(argv) == 0
    qry = sorted((route / "qry").iterdir())
    test_queries = {str(p) for p in qry[20:]}
    assert len(fits) == 2 and fits[0] and not test_queries & set(fits[0])  # the choice: no test query
    assert {str(p) for p in qry[:20]} <= set(fits[0])
    assert test_queries <= set(fits[1])  # the dataset itself: fitted as asked (--fit-on both)
    reason = json.loads((tmp_path / "ds" / "dataset.json").read_text())["descriptor_choice"]["reason"]
    assert "by the val proxy's model-free raw+seqmatch R@1" in reason  # its figures: the proxy's, fitted on fewer
    assert (f"(the proxy's figures: its fitted state on {len(fits[0])} images, the final descriptors' on "
            f"{len(fits[1])}, so their val R@1 differ)") in reason and len(fits[0]) < len(fits[1])
