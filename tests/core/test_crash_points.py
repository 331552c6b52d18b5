"""Crash consistency: a writer killed (``os._exit``, as ``kill -9``) before or after any rename it makes
leaves its output either wholly the old version or wholly the new one — never missing, never mixed —
and the next writer repairs what the dead one left (no ``.old`` / ``.tmp`` stays behind)."""

from __future__ import annotations

import pytest
from conftest import run_killed

import seqnet.security.dirs as dirs
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic


def _leftovers(root):
    return sorted(p.name for p in root.parent.iterdir() if p.name.startswith(f".{root.name}.") and
                  not p.name.endswith(".lock"))


@pytest.mark.parametrize("when", ["before", "after"])
def test_dataset_replacement_is_never_missing_or_mixed(tmp_path, when):
    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    for k in range(1, 40):
        save_dataset(old, root, overwrite=True)
        code = run_killed(k, when, save_dataset, new, root, True)
        got = load_dataset(root)  # always there, always one whole version
        assert got.name in ("old", "new"), k
        want = new if got.name == "new" else old
        assert (got.reference.descriptors == want.reference.descriptors).all(), k
        save_dataset(old, root, overwrite=True)  # the next writer repairs what the dead one left
        assert _leftovers(root) == [] and load_dataset(root).name == "old"
        if code == 0:  # the writer made fewer than k renames: every crash point was tried
            break
    else:
        pytest.fail("more renames than expected")
    assert k > 3


def test_an_interrupted_two_step_replacement_is_repaired(tmp_path, monkeypatch):
    """Where the file system cannot exchange directories, the old one is moved aside first; killed
    there, the next writer (or reader after it) finds it restored."""
    monkeypatch.setattr(dirs, "exchange", lambda a, b: False)
    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    save_dataset(old, root)
    for k in range(1, 40):
        code = run_killed(k, "after", save_dataset, new, root, True)
        save_dataset(old, root, overwrite=True)
        assert load_dataset(root).name == "old" and _leftovers(root) == []
        if code == 0:
            break


def test_a_reader_during_a_replacement_sees_one_version(tmp_path, monkeypatch):
    """The dataset is replaced between the reader's reading of its two traverses: the reader starts again
    and returns the new version whole (never the old reference with the new query)."""
    import seqnet.data.io as io

    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    save_dataset(old, root)
    real, calls = io.load_traverse, []

    def replacing(*a, **kw):
        t = real(*a, **kw)
        calls.append(1)
        if len(calls) == 1:
            save_dataset(new, root, overwrite=True)  # a writer swaps the directory in mid-read
        return t

    monkeypatch.setattr(io, "load_traverse", replacing)
    got = load_dataset(root)
    assert got.name == "new" and len(calls) > 2
    assert (got.reference.descriptors == new.reference.descriptors).all()
    assert (got.query.descriptors == new.query.descriptors).all()


def _each_crash_point(target, *args, check) -> int:
    """Kill ``target(*args)`` before and after each of its renames in turn; ``check()`` after every kill."""
    tried = 0
    for when in ("before", "after"):
        for k in range(1, 60):
            code = run_killed(k, when, target, *args)
            check()
            tried += 1
            if code == 0:
                break
    return tried


def test_describe_output_never_sits_beside_another_runs_sidecars(folder, tmp_path):
    import json

    import numpy as np

    from seqnet.cli import main
    from seqnet.core.provenance import sidecar
    from seqnet.data.readers import bound_names, read_provenance
    from seqnet.describe.stage import names_file_for

    dims = {}
    for size in ("32x16", "16x8"):  # the descriptor size each run's settings give
        p = tmp_path / f"p{size}.npy"
        assert main(["-q", "describe", str(folder), "--method", "pixels", "--resize", size, "--out", str(p)]) == 0
        dims[json.dumps(json.loads(sidecar(p).read_text())["settings"], sort_keys=True)] = np.load(p).shape[1]
    assert len(set(dims.values())) == 2
    out = tmp_path / "d.npy"
    argv = ["-q", "describe", str(folder), "--out", str(out), "--overwrite"]
    assert main([*argv, "--method", "pixels", "--resize", "32x16"]) == 0

    def check():
        # whichever descriptors a kill leaves (the old ones stay until the new are complete), seqnet reads them
        # with their own run's provenance and names (the sidecar holds the replaced output's record meanwhile)
        assert out.exists()
        d = np.load(out)
        assert dims[json.dumps(read_provenance(out)["settings"], sort_keys=True)] == d.shape[1]
        assert len(bound_names(out)) == len(d) == len(names_file_for(out).read_text().split())
        assert main([*argv, "--method", "pixels", "--resize", "32x16"]) == 0  # the next run repairs it

    assert _each_crash_point(main, [*argv, "--method", "pixels", "--resize", "16x8"], check=check) > 4


def test_localize_summary_is_always_its_tracks(synth_dir, tmp_path):
    import csv
    import json

    from seqnet.cli import main
    from seqnet.localize.trackfile import read_summary

    out = tmp_path / "t.csv"
    base = ["-q", "localize", "--dataset", str(synth_dir), "--out", str(out)]
    assert main([*base, "--method", "single"]) == 0

    def check():
        # the old track stays until the new one is complete, and its summary is always beside it: the summary file
        # is bound to its track and holds the replaced track's summary while the new track is renamed in
        assert out.exists() and out.with_suffix(".json").exists()
        rows = list(csv.DictReader(out.open()))
        summary = read_summary(out)
        assert summary["config"]["method"] in ("single", "raw+seqmatch")
        answered = sum(r["estimate"] not in ("", "-1") for r in rows)
        assert summary["summary"]["answered"] == answered
        assert json.loads(out.with_suffix(".json").read_text())["kind"] == "seqnet-localize/1"
        assert main([*base, "--method", "single"]) == 0

    assert _each_crash_point(main, [*base, "--method", "raw+seqmatch"], check=check) >= 4


def _user_files(out):
    """A user's own files in the output folder: a file and a subfolder (kept, same inode, by every eval)."""
    (out / "sub").mkdir(parents=True, exist_ok=True)
    (out / "mine.txt").write_text("my notes")
    (out / "sub" / "notes.md").write_text("my sub notes")
    return {p: (p.read_text(), p.stat().st_ino) for p in (out / "mine.txt", out / "sub" / "notes.md")}


def _eval_set(out, figures, kinds) -> str:
    """The evaluation whose set ``out`` holds, checked whole: results.json, its own pr_curve.png (``figures``:
    method -> hash), report.html (present exactly when that run made one), per-query rows of its method, and a
    manifest listing exactly these; ``kinds``: method -> whether its run made a report."""
    import hashlib
    import json

    (method,) = json.loads((out / "results.json").read_text())["methods"]
    assert hashlib.sha256((out / "pr_curve.png").read_bytes()).hexdigest() == figures[method], method
    want = {"results.json", "pr_curve.png", "pq.csv"} | ({"report.html"} if kinds[method] else set())
    if kinds[method]:
        text = (out / "report.html").read_text()
        assert all((f"<td>{m}</td>" in text) == (m == method) for m in kinds), method
    assert set(json.loads((out / ".seqnet-manifest.json").read_text())["files"]) == want, method
    rows = (out / "pq.csv").read_text().splitlines()[1:]
    assert rows and {r.split(",")[0] for r in rows} == {method}
    return method


def _eval_kill_test(out, old, new, kinds):
    """``old`` then ``new`` (argv; ``kinds``: each one's method -> whether it makes a report): ``new`` killed at
    every rename leaves ``out`` holding ``old``'s set whole or ``new``'s whole, and the user's files as they
    were; the next run repairs what the dead one left."""
    import hashlib
    import json

    from seqnet.cli import main

    user = _user_files(out)
    figures = {}
    for argv in (new, old):  # each evaluation's own figure; ``old`` last: the set every kill starts from
        assert main(argv) == 0
        (method,) = json.loads((out / "results.json").read_text())["methods"]
        figures[method] = hashlib.sha256((out / "pr_curve.png").read_bytes()).hexdigest()
    assert len(set(figures.values())) == 2
    seen = set()

    def check():
        seen.add(_eval_set(out, figures, kinds))
        assert {p: (p.read_text(), p.stat().st_ino) for p in user} == user  # untouched, never copied
        assert main(old) == 0  # the next run repairs what the dead one left
        assert _leftovers(out) == []

    assert _each_crash_point(main, new, check=check) >= 6
    assert len(seen) == 2  # some kills left the old set, the others the new one


@pytest.mark.parametrize("new_report", [True, False])
def test_eval_outputs_never_mix_two_evaluations(synth_dir, tmp_path, new_report):
    """``eval --out DIR`` with a report and a per-query file in DIR: a kill at any step leaves the old set or the
    new one (without a report, the old run's report.html leaves with its set), never a mix; the user's files stay."""
    out = tmp_path / "ev"
    base = ["-q", "eval", "--dataset", str(synth_dir), "--out", str(out), "--per-query", str(out / "pq.csv")]
    old = [*base, "--method", "single", "--report"]
    new = [*base, "--method", "raw+seqmatch", *(["--report"] if new_report else [])]
    _eval_kill_test(out, old, new, {"single": True, "raw+seqmatch": new_report})


def test_eval_on_a_matrix_never_mixes_with_an_earlier_set(synth_dir, synth_dataset, tmp_path):
    """``eval --distances`` replaces the whole set (its own pr_curve.png, report.html and per-query file) at once."""
    import numpy as np

    q, r = synth_dataset.query.descriptors, synth_dataset.reference.descriptors
    np.save(tmp_path / "d.npy", np.sqrt(((q[:, None, :] - r[None]) ** 2).sum(-1)))
    out = tmp_path / "ev"
    base = ["-q", "eval", "--dataset", str(synth_dir), "--out", str(out), "--per-query", str(out / "pq.csv")]
    old = [*base, "--method", "single", "--report"]
    new = [*base, "--distances", str(tmp_path / "d.npy"), "--method", "raw+seqmatch", "--report"]
    _eval_kill_test(out, old, new, {"single": True, "raw+seqmatch": True})


def test_eval_against_a_map_never_mixes_with_an_earlier_set(synth_dir, tmp_path):
    """``eval --index MAP`` (no report) replaces an earlier evaluation's set, its report.html included, at once."""
    from seqnet.cli import main

    assert main(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                 "raw+seqmatch", "--seq-len", "4", "--out", str(tmp_path / "map")]) == 0
    out = tmp_path / "ev"
    base = ["-q", "eval", "--dataset", str(synth_dir), "--out", str(out), "--per-query", str(out / "pq.csv")]
    old = [*base, "--method", "single", "--report"]
    new = [*base, "--index", str(tmp_path / "map"), "--method", "delta"]
    _eval_kill_test(out, old, new, {"single": True, "delta": False})


def test_the_next_writer_removes_what_killed_writers_left(synth_dir, folder, tmp_path):
    """Temporary files of atomic writes that a killed run left beside its outputs (named with seqnet's mark) are
    removed by the next run of the same output (it holds the lock, so no live writer owns them); other files,
    a user's own files named like them without the mark included, are kept."""
    from seqnet.cli import main

    track, ev, desc = tmp_path / "t.csv", tmp_path / "ev", tmp_path / "d.npy"
    ev.mkdir()
    dead = [tmp_path / ".t.csv.seqnet-abc123.tmp", tmp_path / ".t.json.seqnet-abc123.tmp",
            ev / ".results.json.seqnet-x1.tmp", ev / ".pr_curve.png.seqnet-x2.tmp", tmp_path / ".d.npy.seqnet-zz.tmp",
            tmp_path / ".d.names.txt.seqnet-zz.tmp"]
    # a user's own files: another output's temporary file, and names like seqnet's without its mark
    keep = [tmp_path / ".other.csv.seqnet-abc.tmp", ev / "mine.txt", tmp_path / ".t.csv.abc123.tmp",
            ev / ".results.json.x1.tmp"]
    for p in dead + keep:
        p.write_text("left behind")
    assert main(["-q", "localize", "--dataset", str(synth_dir), "--method", "single", "--out", str(track)]) == 0
    assert main(["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(ev)]) == 0
    assert main(["-q", "describe", str(folder), "--method", "pixels", "--out", str(desc)]) == 0
    assert not [p for p in dead if p.exists()] and all(p.exists() for p in keep)
