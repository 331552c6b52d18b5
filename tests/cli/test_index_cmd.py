"""``seqnet index build``'s 'evaluate with:' command runs as printed (hunt 5 F2: a causal map's needed --window)."""

from __future__ import annotations

import shlex

import pytest

from seqnet.cli import main as cli
from seqnet.cli.index_cmd import eval_command


@pytest.mark.parametrize(("flags", "want"), [
    (["--window", "causal"], "--window causal"),
    (["--split", "val"], "--split val"),
])
def test_the_printed_eval_command_runs(synth_dir, tmp_path, capsys, flags, want):
    mp = tmp_path / "map"
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                "raw+seqmatch", "--seq-len", "4", *flags, "--out", str(mp)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if "evaluate with: " in x)
    argv = shlex.split(line.split("evaluate with: ", 1)[1])
    assert argv[:2] == ["seqnet", "eval"] and want in shlex.join(argv)
    assert cli([*argv[1:], "--out", str(tmp_path / "e")]) == 0, capsys.readouterr().err


def test_a_whole_map_of_explicit_positives_names_its_split():
    meta = {"config": {"window": "centred"}, "source": {"split": "all", "explicit_positives": True}}
    assert eval_command(meta, "m p", "ds") == "seqnet eval --index 'm p' --dataset ds --split all"
    meta["source"]["explicit_positives"] = False  # radius: the test queries against the whole route
    assert eval_command(meta, "m", "ds") == "seqnet eval --index m --dataset ds"
