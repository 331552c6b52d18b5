"""``seqnet eval``'s printed notes beside the table."""

from __future__ import annotations

from seqnet.cli import main as cli_main


def test_a_tiny_query_range_gets_a_small_sample_note(synth_dir, capsys):
    base = ["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--seq-len", "3"]
    assert cli_main([*base, "--split", "0:150,10:16"]) == 0
    out = capsys.readouterr().out
    assert "note: only 6 queries scored: one query changes R@1 by 1/6 = 0.167; 95% intervals of R@1 (Wilson): " \
        "single " in out, out
    assert cli_main([*base, "--split", "test"]) == 0
    assert "queries scored" not in capsys.readouterr().out  # a test split of 30 or more queries: nothing said


def test_the_small_sample_note_is_kept_in_the_results_and_the_report(synth_dir, tmp_path, capsys):
    """The note is not only printed: results.json keeps it and the report's notes say it (as the table is read)."""
    import json

    out = tmp_path / "out"
    assert cli_main(["-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--seq-len", "3",
                     "--split", "0:150,10:16", "--out", str(out), "--report"]) == 0
    note = json.loads((out / "results.json").read_text())["few_queries"]
    assert note.startswith("only 6 queries scored: one query changes R@1 by 1/6"), note
    assert "only 6 queries scored" in (out / "report.html").read_text()
    assert f"note: {note}" in capsys.readouterr().out


def test_a_dataset_changed_since_seqnet_wrote_it_is_warned_at_default_verbosity(synth_dir, tmp_path, capsys):
    """The warning that a dataset's files changed since seqnet wrote it reaches stderr without -v (it went through
    Python warnings, which the CLI shows only with -v), once."""
    import shutil

    import numpy as np

    root = tmp_path / "edited"
    shutil.copytree(synth_dir, root)
    q = np.load(root / "query" / "descriptors.npy")
    np.save(root / "query" / "descriptors.npy", q[::-1].copy())
    assert cli_main(["eval", "--dataset", str(root), "--method", "single", "--seq-len", "3"]) == 0
    err = capsys.readouterr().err
    assert err.count("query/descriptors.npy changed since seqnet wrote the dataset") == 1, err
