"""``eval --index``: which maps a dataset's queries may be scored against (frame-number positions of another
dataset are unrelated places; metres of another traverse of the same area are not), in the unit of the positions,
and what the notes say of a map's methods."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.data.io import save_dataset
from seqnet.eval.evaluate import EvalConfig
from seqnet.maps import MapConfig, build, evaluate_main

FREE = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4)  # a model-free map
CONF = EvalConfig(methods=["hvpr-delta:raw+seqmatch"], seq_len=4)


def framed(ds, name: str):
    """``ds`` with frame numbers as positions (query i is reference i's place; radius 1 frame)."""
    n = min(len(ds.reference), len(ds.query))
    ref = dataclasses.replace(ds.reference.subset(0, n), positions=np.arange(n, dtype=np.float64)[:, None])
    qry = dataclasses.replace(ds.query.subset(0, n), positions=np.arange(n, dtype=np.float64)[:, None])
    return dataclasses.replace(ds, reference=ref, query=qry, radius=1.0, position_unit="frames", name=name,
                               splits={"a": {"reference": (0, n // 2), "query": (0, n // 2)},
                                       "b": {"reference": (n // 2, n), "query": (n // 2, n)}})


def test_a_map_in_metres_against_a_dataset_of_frame_numbers_names_each_unit(synth_dataset, tmp_path):
    """A map built from a metres dataset, scored on another dataset whose positions are frame numbers: each
    side's unit is said as it is (the map's positions are metres, not frame numbers)."""
    a = save_dataset(framed(synth_dataset, "A"), tmp_path / "A")
    n = min(len(synth_dataset.reference), len(synth_dataset.query))
    metres = dataclasses.replace(synth_dataset, name="M", reference=synth_dataset.reference.subset(0, n),
                                 query=synth_dataset.query.subset(0, n),
                                 splits={"a": {"reference": (0, n // 2), "query": (0, n // 2)}})
    map_m = build(FREE.replace(split="a"), save_dataset(metres, tmp_path / "M"), tmp_path / "mapM")
    with pytest.raises(ConfigError) as e:
        evaluate_main(CONF.replace(split="a"), a, map_m, tmp_path / "o1")
    assert f"dataset {a} gives positions as frame numbers and map {tmp_path / 'mapM'} as metres, but the map was " \
           "built from" in str(e.value)
    assert str(e.value).endswith(": frame numbers and metres do not name the same places; hint: build the map "
                                 "from this dataset and split")


def test_a_map_of_another_dataset_with_frame_numbers_is_refused(synth_dataset, tmp_path, capsys):
    a = save_dataset(framed(synth_dataset, "A"), tmp_path / "A")
    other = framed(synth_dataset, "B")  # the same numbering, but another dataset's images
    other = dataclasses.replace(other, reference=dataclasses.replace(
        other.reference, names=[f"other-{i:05d}.png" for i in range(len(other.reference))]))
    b = save_dataset(other, tmp_path / "B")
    map_b = build(FREE.replace(split="a"), b, tmp_path / "mapB")
    with pytest.raises(ConfigError, match="give positions as frame numbers, but the map was built from .*B \\[a\\]: "
                                          "frame numbers of two datasets do not name the same places; hint: build "
                                          "the map from this dataset and split"):
        evaluate_main(CONF.replace(split="a"), a, map_b, tmp_path / "o1")
    capsys.readouterr()
    assert cli(["eval", "--dataset", str(a), "--index", str(map_b), "--split", "a", "--seq-len", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame numbers of two datasets" in err[0], err
    map_a = build(FREE.replace(split="a"), a, tmp_path / "mapA")  # this dataset's map: scored
    assert evaluate_main(CONF.replace(split="a"), a, map_a, tmp_path / "o2").data["methods"]
    # another split of this dataset: its frame numbers are the same numbering, so no place is within the radius;
    # the error says the positions' unit
    with pytest.raises(ConfigError, match="has a reference within radius 1 frames"):
        evaluate_main(CONF.replace(split="b"), a, map_a, tmp_path / "o3")


def test_a_frames_dataset_moved_after_its_map_was_built_is_scored(synth_dataset, tmp_path):
    a = save_dataset(framed(synth_dataset, "A"), tmp_path / "A")
    map_a = build(FREE.replace(split="a"), a, tmp_path / "mapA")
    moved = shutil.move(str(a), str(tmp_path / "moved"))  # the same reference names and frame numbers
    assert evaluate_main(CONF.replace(split="a"), moved, map_a, tmp_path / "o").data["methods"]


def test_a_map_of_another_traverse_in_metres_is_scored(synth_dir, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(synth_dir, other)  # another dataset directory, positions in metres (UTM): the same area
    mp = build(FREE, other, tmp_path / "map")
    assert evaluate_main(CONF, synth_dir, mp, tmp_path / "o").data["methods"]["hvpr-delta:raw+seqmatch"]["queries"]


def test_the_baseline_note_of_a_map_runs_without_index(synth_dir, map_models, tmp_path, capsys):
    mp = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--model", str(map_models[1]), "--shortlist",
                "s1", "--rerank", "s1+seqmatch", "--out", str(mp)]) == 0
    capsys.readouterr()
    assert cli(["eval", "--dataset", str(synth_dir), "--index", str(mp)]) == 0
    note = [line for line in capsys.readouterr().out.splitlines() if "no model-free counterpart" in line]
    assert len(note) == 1, note
    assert note[0].endswith(f"(map {mp} serves only its own methods; to see whether the model helps, evaluate the "
                            f"model-free baseline without --index: seqnet eval --dataset {synth_dir} --split test "
                            "--method raw+seqmatch,single)"), note
    assert "(add " not in note[0]
