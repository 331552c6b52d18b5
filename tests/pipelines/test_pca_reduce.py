"""--pca D: a PCA fitted on the train split only, applied to every frame, recorded with the dataset."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.describe.pca import PCA, read_tag
from seqnet.pipelines.pca import fit_on_split, main, pca_path, reduce_dataset, split_frames


def _with_other_test_and_val(ds):
    """``ds`` whose val and test frames (outside the train ranges) are replaced by large random ones."""
    rng = np.random.default_rng(5)
    sides = {}
    for side in ("reference", "query"):
        t = getattr(ds, side)
        desc = np.array(t.descriptors, np.float32)
        a, b = ds.splits["train"][side]
        outside = np.ones(len(desc), bool)
        outside[a:b] = False
        desc[outside] = 100 * rng.standard_normal((int(outside.sum()), desc.shape[1]))
        sides[side] = dataclasses.replace(t, descriptors=desc)
    return dataclasses.replace(ds, **sides)


def test_the_pca_sees_the_train_split_only(synth_dataset):
    pca = fit_on_split(synth_dataset, 4)
    train = synth_dataset.split("train")
    frames = np.concatenate([train.reference.descriptors, train.query.descriptors])
    assert np.allclose(pca.mean, frames.mean(axis=0), atol=1e-5)
    assert split_frames(synth_dataset, "train").shape == (len(frames), 16)
    other = fit_on_split(_with_other_test_and_val(synth_dataset), 4)
    assert np.array_equal(other.mean, pca.mean) and np.array_equal(other.components, pca.components)
    # and the check can fail: the whole dataset gives another PCA
    whole = dataclasses.replace(synth_dataset, splits={**synth_dataset.splits, "train": {
        "reference": (0, len(synth_dataset.reference)), "query": (0, len(synth_dataset.query))}})
    assert not np.allclose(fit_on_split(whole, 4).mean, pca.mean)


def test_reduce_projects_every_frame_and_records_it(synth_dataset):
    reduced, pca = reduce_dataset(synth_dataset, 4)
    assert reduced.query.dim == reduced.reference.dim == 4 and len(reduced.query) == len(synth_dataset.query)
    assert np.allclose(reduced.query.descriptors, pca.transform(np.asarray(synth_dataset.query.descriptors)))
    prov = reduced.reference.provenance
    assert prov == reduced.query.provenance and prov["id"] != synth_dataset.reference.provenance["id"]
    assert prov["settings"]["dim"] == 4 and prov["settings"]["pca_on"] == "train"
    assert reduced.extra["pca"]["fit_split"] == "train" and reduced.extra["pca"]["input_dim"] == 16
    with pytest.raises(ConfigError, match="no such split"):
        reduce_dataset(dataclasses.replace(synth_dataset, splits={}), 4)
    with pytest.raises(ConfigError, match="does not reduce"):
        reduce_dataset(synth_dataset, 16)


def test_main_writes_beside_then_reuses(synth_dataset, tmp_path):
    src = save_dataset(synth_dataset, tmp_path / "ds")
    out = main(src, 8)
    assert out == tmp_path / "ds-pca8" and load_dataset(out).query.dim == 8
    assert read_tag(pca_path(out)) == load_dataset(out).reference.provenance["id"]
    assert PCA.load(pca_path(out)).dims == 8
    stamp = (out / "dataset.json").stat().st_mtime_ns
    assert main(src, 8) == out and (out / "dataset.json").stat().st_mtime_ns == stamp  # reused
    (tmp_path / "ds-pca4").mkdir()
    save_dataset(synth_dataset, tmp_path / "ds-pca4", overwrite=True)  # something else under that name
    with pytest.raises(ConfigError, match="is not"):
        main(src, 4)


def test_pca_on_a_reduced_dataset_is_warned_naming_the_unreduced_one(synth_dataset, tmp_path, caplog):
    """``seqnet train --pca 4`` on a dataset already reduced (``ds-pca8``, or a ``from-images --pca`` one) wrote a
    twice-reduced dataset without a word, whose map cannot take images: one warning names the unreduced dataset
    beside it when there is one, else the rebuild; the chain is recorded (``input_pca``); an unreduced dataset
    stays silent."""
    import logging

    caplog.set_level(logging.WARNING, logger="seqnet")
    src = save_dataset(synth_dataset, tmp_path / "ds")
    once = main(src, 8)
    assert not [r for r in caplog.records if "already reduced" in r.getMessage()]  # the unreduced dataset: silent
    caplog.clear()  # (the cost of --pca 8 was said: tests/pipelines/test_pca_measured.py)
    twice = main(once, 4)
    said = [r.getMessage() for r in caplog.records if not r.getMessage().startswith("--pca 4 ")]  # its cost line
    assert said == [f"{once} is already reduced by a PCA (16-D to 8-D): --pca 4 reduces it a second time, and "
                    "localize, index build and serve apply one PCA to the query images they describe, so its map "
                    "will not take images (descriptor files only); hint: reduce the unreduced descriptors once: "
                    f"seqnet train --dataset {src} --pca 4"], said
    assert load_dataset(twice).extra["pca"]["input_pca"] == {"dims": 8, "input_dim": 16,
                                                             "source": synth_dataset.reference.provenance["id"]}
    caplog.clear()
    main(save_dataset(load_dataset(once), tmp_path / "alone"), 4)  # reduced, nothing unreduced beside it
    said = [r for r in caplog.records if not r.getMessage().startswith("--pca 4 ")]
    assert len(said) == 1 and said[0].getMessage().endswith(
        "hint: reduce the unreduced descriptors once: build the dataset with seqnet dataset from-images --pca 4 (or "
        "without --pca, then seqnet train --pca 4 on it)")


def test_cli_train_with_pca(synth_dataset, tmp_path, capsys):
    src = save_dataset(synth_dataset, tmp_path / "ds")
    common = ["--epochs", "1", "--optimizer", "adam", "--n-neg-sample", "50", "--device", "cpu", "--seq-len", "3",
              "--w", "2"]
    assert cli_main(["train", "--dataset", str(src), "--pca", "8", "--out", str(tmp_path / "r"), *common]) == 0
    out = capsys.readouterr().out
    assert f"--dataset {(tmp_path / 'ds-pca8').resolve()}" in out and "D=8->8" in out
    assert cli_main(["train", "--resume", str(tmp_path / "r"), "--pca", "8"]) == 2
    assert "--pca applies when a run starts" in capsys.readouterr().err


def test_dims_must_be_below_the_train_frames(synth_dataset):
    """N centred frames span at most N - 1 axes: ``--pca N`` on N train frames (was accepted: its last axis
    arbitrary) is refused, as ``seqnet train --pca`` reaches it; N - 1 fits."""
    small = dataclasses.replace(synth_dataset, splits={"train": {"reference": (0, 4), "query": (0, 4)}})
    with pytest.raises(ConfigError, match=r"--pca 8: the 'train' split has 8 frames, and a PCA fitted on them has "
                                          r"at most 7 axes .* \(hint: --pca 2 or a larger train split\)"):
        reduce_dataset(small, 8)
    assert reduce_dataset(small, 7)[0].query.dim == 7


def test_the_reduced_descriptors_keep_the_size_their_images_had(synth_dataset):
    """Each side's image size stays beside the one id (a map reduced by --pca recorded none, so a portrait query
    of the same D passed localize and serve); a side without one stays without."""
    from seqnet.core.provenance import image_size_of, make

    ref = make("describe", {"method": "pixels"}, dim=synth_dataset.reference.dim, image_size=(64, 32))
    qry = make("describe", {"method": "pixels"}, dim=synth_dataset.query.dim, image_size=(48, 24))
    ds = dataclasses.replace(synth_dataset, reference=dataclasses.replace(synth_dataset.reference, provenance=ref),
                             query=dataclasses.replace(synth_dataset.query, provenance=qry))
    reduced, _ = reduce_dataset(ds, 4)
    assert image_size_of(reduced.reference.provenance) == (64, 32)
    assert image_size_of(reduced.query.provenance) == (48, 24)
    assert reduced.reference.provenance["id"] == reduced.query.provenance["id"]
    plain, _ = reduce_dataset(synth_dataset, 4)
    assert image_size_of(plain.reference.provenance) is None
