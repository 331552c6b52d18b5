"""The CLI: `seqnet synth` and `seqnet eval`, and every user error as one stderr line + exit code 2."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqnet.cli import main


@pytest.fixture(scope="module")
def small_dir(tmp_path_factory):
    """A small synthetic dataset written by `seqnet synth` (module scope: written once)."""
    root = tmp_path_factory.mktemp("cli") / "ds"
    assert main(["-q", "synth", str(root), "--places", "120", "--dim", "8", "--seed", "3"]) == 0
    return root


@pytest.fixture
def ds_copy(small_dir, tmp_path):
    dst = tmp_path / "ds"
    shutil.copytree(small_dir, dst)
    return dst


def run_error(capsys, argv, pattern):
    """Run the CLI expecting a user error: exit 2, one stderr line naming the problem, no traceback."""
    capsys.readouterr()
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 2, (rc, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert pattern in lines[0], lines[0]
    return lines[0]


def test_synth_then_eval(small_dir, capsys, tmp_path):
    out_json = tmp_path / "res" / "results.json"
    rc = main(["eval", "--dataset", str(small_dir), "--method", "single,raw+seqmatch",
               "--method", "hvpr-delta:raw+seqmatch",
               "--seq-len", "3", "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "raw+seqmatch" in out and "queries evaluated" in out and "[test]" in out
    res = json.loads(out_json.read_text())
    assert list(res["methods"]) == ["single", "raw+seqmatch", "hvpr-delta:raw+seqmatch"]
    assert res["config"]["seq_len"] == 3 and res["config"]["split"] == "test"
    assert res["config"]["dataset_path"] == str(small_dir)
    assert not [p for p in out_json.parent.iterdir() if p.name != "results.json"]  # no temp files left


def test_eval_defaults_all_split_and_seq_len_one(small_dir, capsys):
    argv = ["-q", "eval", "--dataset", str(small_dir), "--split", "all", "--seq-len", "1", "--backend", "faiss"]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert "single" in out and "delta" not in out  # Delta methods need L >= 2: left out of the defaults
    assert err == ""


def test_logging_follows_captured_stderr(small_dir, capsys):
    # main() runs many times in one process: log lines must go to the current sys.stderr each time
    for _ in range(2):
        assert main(["-v", "eval", "--dataset", str(small_dir), "--method", "single", "--seq-len", "2"]) == 0
        _, err = capsys.readouterr()
        assert "single: R@1" in err and "Logging error" not in err


def test_synth_outputs(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "s"), "--places", "100", "--dim", "8"]) == 0
    out, err = capsys.readouterr()
    assert "wrote" in out and (tmp_path / "s" / "dataset.json").is_file()
    assert "wrote" not in err  # said once: it was said again on stderr, in other words


# ----------------------------------------------------------------------------- error paths


def test_nonexistent_dataset(tmp_path, capsys):
    run_error(capsys, ["eval", "--dataset", str(tmp_path / "nope")], "dataset directory not found")


def test_garbage_descriptors(ds_copy, capsys):
    (ds_copy / "query" / "descriptors.npy").write_bytes(b"this is not a numpy file\n" * 10)
    line = run_error(capsys, ["eval", "--dataset", str(ds_copy)], "descriptors.npy")
    assert line.startswith("seqnet eval: error: ")


@pytest.mark.parametrize("value, pattern", [("0", "--seq-len"), ("abc", "--seq-len"), ("-3", "--seq-len"),
                                            ("100000", "longer than the")])
def test_bad_seq_len(small_dir, capsys, value, pattern):
    run_error(capsys, ["eval", "--dataset", str(small_dir), "--seq-len", value], pattern)


def test_dim_mismatch(ds_copy, capsys):
    n = len(np.load(ds_copy / "query" / "descriptors.npy"))
    np.save(ds_copy / "query" / "descriptors.npy", np.ones((n, 9), np.float32))
    run_error(capsys, ["eval", "--dataset", str(ds_copy)], "dimension mismatch: reference D=8, query D=9")


def test_count_mismatch_and_nan(ds_copy, capsys):
    d = np.load(ds_copy / "reference" / "descriptors.npy")
    d[4, 0] = np.nan
    np.save(ds_copy / "reference" / "descriptors.npy", d)
    run_error(capsys, ["eval", "--dataset", str(ds_copy)], "NaN or inf (first at row 4, image reference_000004.png)")
    d[4, 0] = 0.0
    np.save(ds_copy / "reference" / "descriptors.npy", d[:-1])
    run_error(capsys, ["eval", "--dataset", str(ds_copy)], "positions for")


def test_missing_json_and_bad_json(ds_copy, capsys):
    (ds_copy / "dataset.json").write_text("{")
    run_error(capsys, ["eval", "--dataset", str(ds_copy)], "not valid JSON")
    (ds_copy / "dataset.json").unlink()
    run_error(capsys, ["eval", "--dataset", str(ds_copy)], "dataset.json is missing")


@pytest.mark.parametrize("argv, pattern", [
    (["--method", "nope"], "unknown method 'nope'"),
    (["--split", "holdout"], "no split 'holdout'"),
    (["--radius", "0"], "--radius"),
    (["--window", "middle"], "--window"),
    (["--method", "seqnet"], "needs an S_L model"),
    (["--seq-len", "1", "--method", "delta"], "need seq_len >= 2"),
    (["--device", "quantum"], "unknown device"),
    (["--top-k", "0"], "--top-k"),
    (["--method", "hvpr-nope"], "shortlister"),
    (["--shortlist", "seqnet"], "unrecognized arguments"),
    (["--method", "single,raw+seqmatch", "--top-k", "5"], "--top-k is the HVPR shortlist size"),  # options of
    (["--method", "hvpr-delta:raw+seqmatch", "--fuse-weight", "0.5"], "--fuse-weight is hvpr-fused"),  # another
    (["--method", "hvpr-delta:raw+seqmatch", "--fuse-top-k", "50"], "--fuse-top-k is hvpr-fused"),  # method
    (["--method", "single,delta", "--rerank-seq-len", "3"], "none of the methods given"),
])
def test_bad_options(small_dir, capsys, tmp_path, argv, pattern):
    out_json = tmp_path / "r.json"
    run_error(capsys, ["eval", "--dataset", str(small_dir), "--json", str(out_json), *argv], pattern)
    assert not out_json.exists()  # nothing half-written
    assert list(tmp_path.iterdir()) == []


def test_usage_errors(capsys):
    run_error(capsys, [], "required: COMMAND")
    run_error(capsys, ["eval"], "required: --dataset")
    run_error(capsys, ["frobnicate"], "invalid choice")
    run_error(capsys, ["eval", "--dataset", "x", "--bogus"], "unrecognized arguments")


def test_help_and_version_exit_zero(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    with pytest.raises(SystemExit) as e:
        main(["eval", "--help"])
    assert e.value.code == 0 and "--seq-len" in capsys.readouterr().out


def test_synth_errors(small_dir, tmp_path, capsys):
    run_error(capsys, ["synth", str(small_dir)], "exists and is not empty")
    run_error(capsys, ["synth", str(tmp_path / "x"), "--places", "50"], "--places: expected an integer >= 100")
    run_error(capsys, ["synth", str(tmp_path / "y"), "--dim", "0"], "--dim")
    (tmp_path / "file").write_text("x")
    run_error(capsys, ["synth", str(tmp_path / "file"), "--overwrite"], "not a directory")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # no temporary directories left


def test_synth_overwrite(ds_copy, capsys):
    before = len(np.load(ds_copy / "query" / "descriptors.npy"))
    assert main(["-q", "synth", str(ds_copy), "--places", "150", "--dim", "8", "--overwrite"]) == 0
    assert len(np.load(ds_copy / "query" / "descriptors.npy")) != before


def test_console_script_subprocess(ds_copy):
    """The installed `seqnet` script: a real process, exit code 2, one stderr line, no traceback."""
    (ds_copy / "query" / "descriptors.npy").write_bytes(b"garbage")
    exe = shutil.which("seqnet") or str(Path(sys.executable).with_name("seqnet"))
    env = {**os.environ, "PYTHONWARNINGS": "default"}
    proc = subprocess.run([exe, "eval", "--dataset", str(ds_copy)], capture_output=True, text=True, timeout=120,
                          env=env)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("seqnet eval: error: cannot read") and "descriptors.npy" in lines[0]
    assert proc.stdout == ""


@pytest.mark.parametrize("suffix", [".csv", ".jsonl"])
def test_eval_ks_and_per_query(small_dir, capsys, tmp_path, suffix):
    per_query = tmp_path / f"pq{suffix}"
    argv = ["eval", "--dataset", str(small_dir), "--method", "single,raw+seqmatch", "--seq-len", "3",
            "--ks", "1,3", "--per-query", str(per_query), "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "R@3" in out and "R@5" not in out
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    entry = res["methods"]["single"]
    assert set(entry) >= {"recall@1", "recall@3", "auc", "recall@100p"} and 0 <= entry["auc"] <= 1
    text = per_query.read_text()
    n = entry["queries"] + entry["no_positive"]
    if suffix == ".jsonl":
        rows = [json.loads(line) for line in text.splitlines()]
        seq = res["methods"]["raw+seqmatch"]  # its own queries: single queries every frame
        assert len(rows) == n + seq["queries"] + seq["no_positive"] and seq["no_full_window"] > 0
        assert rows[0]["method"] == "single" and len(rows[0]["reference_indices"]) == 3  # K max
        r1 = sum(r["correct"][0] for r in rows if r["method"] == "single" and r["has_positive"]) / entry["queries"]
        assert r1 == pytest.approx(entry["recall@1"])
    else:
        lines = text.splitlines()
        seq = res["methods"]["raw+seqmatch"]
        assert lines[0].startswith("method,query_index,query_name,reference_indices,reference_names")
        assert len(lines) == n + seq["queries"] + seq["no_positive"] + 1


def test_dataset_check_prints_metadata_one_key_a_line(synth_dir, capsys):
    from seqnet.cli import main

    assert main(["dataset", "check", str(synth_dir)]) == 0
    out = capsys.readouterr().out.splitlines()
    meta = out[out.index("  metadata:") + 1 :]
    assert meta and all(line.startswith("    ") and len(line) <= 120 for line in meta), meta


def test_from_images_needs_a_radius_unless_positives_imply_one(folder, tmp_path, capsys):
    from seqnet.cli import main

    (tmp_path / "pos.csv").write_text("query,reference\n" + "".join(f"{i},{i}\n" for i in range(10)))
    base = ["dataset", "from-images", str(folder), str(folder), "--method", "pixels", "--patch", "8"]
    assert main([*base, "--frame-aligned", "--out", str(tmp_path / "a")]) == 2
    assert "--radius is required with frames ground truth" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    assert main([*base, "--positives", str(tmp_path / "pos.csv"), "--out", str(tmp_path / "b")]) == 0
    assert "ground truth positives, radius 1 frames" in capsys.readouterr().out


@pytest.mark.parametrize("argv, pattern", [
    (["--method", "single", "--top-k", "5"], "--top-k is the HVPR shortlist size"),
    (["--method", "single", "--rerank-seq-len", "3"], "--match-len is the length L_m"),
])
def test_localize_refuses_options_of_other_methods(small_dir, capsys, tmp_path, argv, pattern):
    out = tmp_path / "t.csv"
    run_error(capsys, ["localize", "--dataset", str(small_dir), "--out", str(out), *argv], pattern)
    assert not out.exists()


def test_an_unknown_option_is_an_error_of_its_subcommand(capsys):
    from seqnet.cli import main as cli_main

    assert cli_main(["train", "--bogus", "1"]) == 2
    assert capsys.readouterr().err.strip().startswith("seqnet train: error: unrecognized arguments: --bogus 1")
    assert cli_main(["dataset", "from-images", "a", "b", "--method", "pixels", "--out", "x", "--utm-names",
                     "--bogus"]) == 2
    assert "seqnet dataset from-images: error: unrecognized arguments: --bogus" in capsys.readouterr().err


def test_extra_radius_results_are_printed(synth_dir, capsys):
    from seqnet.cli import main as cli_main

    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "single", "--extra-radius", "30"]) == 0
    out = capsys.readouterr().out
    assert "within radius 30 (--extra-radius):" in out
    line = next(x for x in out.splitlines() if x.startswith("  single: R@1 "))
    assert float(line.split("R@1 ")[1].split(",")[0]) >= 0


def test_ordinals_and_a_vpr_tutorial_gt_said_once(tmp_path, caplog):
    import logging

    import numpy as np

    from seqnet.core.log import ordinal
    from seqnet.data.positives import read_positives

    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111)] == \
        ["1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st", "111th"]
    hard = np.eye(5, dtype=bool)
    np.savez(tmp_path / "GT.npz", GThard=hard, GTsoft=hard | np.eye(5, k=1, dtype=bool))
    caplog.set_level(logging.INFO, logger="seqnet")
    read_positives(tmp_path / "GT.npz")
    assert sum("ground-truth matrix" in r.getMessage() for r in caplog.records if r.levelno == logging.INFO) == 1
