"""Square descriptor arrays saved as [D, N] (seqnet.data.orientation): refused when the values decide it, warned
when they suggest it, silent on correctly oriented descriptors (real nordland64 pixels, a PCA output, seqnet synth)
and when they cannot tell; at every route a dataset is made by (Dataset, load_dataset, from-csv)."""

from __future__ import annotations

import numpy as np
import pytest
from data.test_sanity import make
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.cli import main as cli_main
from seqnet.core.errors import DatasetError
from seqnet.data.orientation import OVERRIDE_ENV, read_square
from seqnet.data.sanity import dataset_warnings


def _unit_rows(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def _route(n: int = 120, seed: int = 0) -> np.ndarray:
    """``[n, n]`` descriptors of a route: a random walk in n dimensions of different scales, rows L2-normalised."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(size=(n, n)), axis=0) * rng.uniform(0.2, 3.0, size=n) + rng.normal(size=n) * 20
    return _unit_rows(walk)


@pytest.fixture(scope="module")
def pixels(tmp_path_factory):
    """nordland64 pixels of summer frames (every 10th from 10000): 120 at 12x10 (D = 120, as described), and 240
    at 32x32 (D = 1024)."""
    from conftest import shared_data

    data, root = shared_data("nordland64"), tmp_path_factory.mktemp("orient")
    frames = [f"{data / 'summer' / f'images-{i:05d}.png'}\n" for i in range(10000, 12400, 10)]
    (root / "120.txt").write_text("".join(frames[:120]))
    (root / "240.txt").write_text("".join(frames))
    for size, n, extra in (("12x10", 120, ["--patch", "0"]), ("32x32", 240, [])):
        assert cli_main(["describe", str(root / f"{n}.txt"), "--method", "pixels", "--resize", size, *extra,
                         "--out", str(root / f"{size}.npy"), "--no-progress"]) == 0
    return np.load(root / "12x10.npy"), np.load(root / "32x32.npy")


def test_real_pixels_of_120_frames_with_d_120(pixels):
    x, _ = pixels
    assert x.shape == (120, 120)
    with pytest.raises(DatasetError, match=r"reference descriptors \[120, 120\] look transposed .*np.save"):
        make(np.ascontiguousarray(x.T), np.ascontiguousarray(x.T))
    assert read_square(x).verdict == "rows"
    assert not any("transposed" in w for w in dataset_warnings(make(x, x[::-1].copy())))


def test_real_pixels_cropped_to_120_dims_are_silent_either_way(pixels):
    """Cropped, the rows lose their unit norm and pixels are no PCA: nothing decides, so nothing is said."""
    x = np.ascontiguousarray(pixels[1][:120, :120])
    for arr in (x, np.ascontiguousarray(x.T)):
        ds = make(arr, arr)
        assert not any("transposed" in w for w in dataset_warnings(ds))


def test_a_pca_output_given_transposed_is_refused(pixels):
    """nordland64 pixels reduced to 120 dimensions by a PCA fitted on 240 frames (decreasing variance), rows not
    normalised, 120 of the frames: read as rows; transposed, PCA order and evenness agree: refused."""
    x = pixels[1].astype(np.float64)
    centred = x - x.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2][:120]
    pca = np.ascontiguousarray((centred[::2] @ axes.T).astype(np.float32))
    assert pca.shape == (120, 120) and read_square(pca).verdict == "rows"
    t = read_square(np.ascontiguousarray(pca.T))
    assert t.verdict == "transposed" and t.strong, t.why
    with pytest.raises(DatasetError, match=r"d: the query descriptors \[120, 120\] look transposed .*PCA order"):
        make(pca, np.ascontiguousarray(pca.T))
    assert not any("transposed" in w for w in dataset_warnings(make(pca, pca[::-1].copy())))


def test_the_own_data_repro_shape_crop_of_a_pca():
    """The hostile test's case: a 128-D PCA cropped to 120 (rows near unit norm, not exactly), given [D, N]."""
    walk = _route(300, seed=4).astype(np.float64)
    centred = walk - walk.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2][:128]
    x = _unit_rows(centred[:120] @ axes.T)[:, :120]
    assert read_square(x).verdict != "transposed"
    t = read_square(np.ascontiguousarray(x.T))
    assert t.verdict == "transposed" and t.strong, t.why


def test_suggestive_evidence_is_a_warning_kept_with_the_datasets_others():
    rng = np.random.default_rng(2)
    x = _route(60, seed=2) * rng.uniform(0.98, 1.02, size=(60, 1)).astype(np.float32)  # near-even rows, not unit
    x = (x * rng.uniform(0.5, 1.5, size=60)).astype(np.float32)  # dimensions of different scales
    x /= np.linalg.norm(x, axis=1, keepdims=True) * rng.uniform(0.97, 1.03, size=(60, 1)).astype(np.float32)
    t = np.ascontiguousarray(x.T)
    o = read_square(t)
    assert o.verdict == "transposed" and not o.strong, o.why
    lines = dataset_warnings(make(t, t))
    assert any(w.startswith("d: the reference descriptors are square ([60, 60])") and "np.save(path, x.T)" in w
               for w in lines), lines
    assert not any("transposed" in w for w in dataset_warnings(make(x, x)))


def test_square_but_undecidable_and_small_arrays_are_silent():
    rng = np.random.default_rng(5)
    for arr in (rng.random((60, 60)), rng.normal(size=(60, 60)), _route(10)):
        assert read_square(arr.astype(np.float32)).verdict is None or read_square(arr.astype(np.float32)).verdict \
            == "rows"
        assert not any("transposed" in w for w in dataset_warnings(make(arr.astype(np.float32),
                                                                        arr.astype(np.float32))))
    sym = rng.random((60, 60))
    sym = (sym + sym.T).astype(np.float32)  # a similarity matrix: both readings alike, said by matrix_as_descriptors
    assert read_square(sym).verdict is None
    assert read_square(_route(120)[:, :100]).verdict is None  # not square: its shape decides (elsewhere)


def test_standardised_dimensions_are_not_taken_for_images():
    """Per-dimension standardisation evens the columns as images' norms do, but leaves every column of mean 0."""
    x = _route(80, seed=6).astype(np.float64)
    z = ((x - x.mean(axis=0)) / x.std(axis=0)).astype(np.float32)
    assert read_square(z).verdict != "transposed"


def test_the_override_keeps_the_rows_and_is_recorded(tmp_path, monkeypatch):
    from seqnet.data.io import load_dataset, save_dataset

    t = np.ascontiguousarray(_route(60).T)
    with pytest.raises(DatasetError, match=OVERRIDE_ENV):
        make(t, t)
    monkeypatch.setenv(OVERRIDE_ENV, "1")
    ds = make(t, t)
    assert ds.extra["rows_are_images"] is True
    save_dataset(ds, tmp_path / "ds")
    monkeypatch.delenv(OVERRIDE_ENV)
    assert load_dataset(tmp_path / "ds").reference.descriptors.shape == (60, 60)  # recorded: not refused again
    assert make(t, t, extra={"rows_are_images": True}).reference.dim == 60
    assert not any("transposed" in w for w in dataset_warnings(make(t, t, extra={"rows_are_images": True})))


def test_a_dataset_written_before_is_refused_at_load(tmp_path):
    from seqnet.data.io import load_dataset, save_dataset

    x = _route(60)
    save_dataset(make(x, x[::-1].copy()), tmp_path / "ds")
    for side in ("reference", "query"):
        np.save(tmp_path / "ds" / side / "descriptors.npy", np.ascontiguousarray(np.load(
            tmp_path / "ds" / side / "descriptors.npy").T))
    with pytest.raises(DatasetError, match="look transposed"):
        load_dataset(tmp_path / "ds")


def test_from_csv_refuses_with_one_line_and_exit_2(tmp_path, capsys):
    x = _route(60)
    for side in ("ref", "query"):
        np.save(tmp_path / f"{side}.npy", np.ascontiguousarray(x.T))
        (tmp_path / f"{side}.csv").write_text("name,x,y\n" + "".join(f"f{i}.png,{3.0 * i},0\n" for i in range(60)))
    code = cli_main(["dataset", "from-csv", "--ref-csv", str(tmp_path / "ref.csv"), "--ref-desc",
                     str(tmp_path / "ref.npy"), "--query-csv", str(tmp_path / "query.csv"), "--query-desc",
                     str(tmp_path / "query.npy"), "--radius", "3", "--out", str(tmp_path / "ds")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not (tmp_path / "ds").exists()
    assert err[-1].startswith("seqnet dataset from-csv: error: ") and "look transposed" in err[-1]


@settings(max_examples=40, deadline=None)
@given(n=st.integers(16, 96), seed=st.integers(0, 2**31 - 1), spread=st.floats(0.0, 3.0))
def test_normalised_rows_read_as_rows_and_their_transpose_is_refused(n, seed, spread):
    rng = np.random.default_rng(seed)
    x = _unit_rows(rng.normal(size=(n, n)) * np.exp(spread * rng.normal(size=n)) + rng.normal(size=n))
    assert read_square(x).verdict == "rows"
    o = read_square(np.ascontiguousarray(x.T))
    assert o.verdict == "transposed" and o.strong
