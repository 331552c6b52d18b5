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
