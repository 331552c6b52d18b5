"""VPR-methods-evaluation's predictions folder: NNN is the query's row in the whole query list, whatever the split."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.data.io import load_dataset


def _folder(path) -> dict[str, str]:
    return {p.name: p.read_text() for p in sorted(path.iterdir()) if not p.name.startswith(".")}


@pytest.mark.parametrize("route", ["descriptors", "distances", "index"])
def test_a_query_keeps_its_number_on_a_split(synth_dir, tmp_path, route):
    """VME's save_preds names a query's file by its index in the query list (``enumerate`` over every query):
    the test split's queries were numbered from 000 (the report's M1: row 152 written as 002.txt)."""
    whole = load_dataset(synth_dir)
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single"]
    if route == "distances":
        q, r = whole.query.descriptors, whole.reference.descriptors
        np.save(tmp_path / "d.npy", np.sqrt(((q[:, None, :] - r[None]) ** 2).sum(-1)))
        argv += ["--distances", str(tmp_path / "d.npy")]
    if route == "index":
        assert main(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                     "raw+seqmatch", "--seq-len", "4", "--out", str(tmp_path / "map")]) == 0
        argv = [*argv[:-1], "delta", "--index", str(tmp_path / "map")]
    a, b = whole.ranges("test")["query"]
    assert main([*argv, "--split", "test", "--per-query", str(tmp_path / "test")]) == 0
    test = _folder(tmp_path / "test")
    numbers = sorted(int(n[:3]) for n in test)
    assert a > 0 and a <= numbers[0] <= a + 2 and b - 3 <= numbers[-1] < b  # windows of L=4 (index) leave out ends
    assert numbers == list(range(a, b)) or route == "index"
    for name, text in test.items():  # the query named in the file is that row of the whole query list
        assert text.split("\n")[1] == whole.query.names[int(name[:3])]
    if route == "index":
        return  # a map is of the whole reference: --split all would score its own frames
    assert main([*argv, "--split", "all", "--per-query", str(tmp_path / "all")]) == 0
    every = _folder(tmp_path / "all")
    assert sorted(every) == [f"{i:03d}.txt" for i in range(len(whole.query))]
    assert all(every[n].split("\n")[1] == test[n].split("\n")[1] for n in test)
