"""A one-value option given twice is refused (one line naming both, exit 2), never the last taken silently;
options meant to repeat (``--model``, ``--split``, ``--db``) repeat as before; the same value twice is harmless."""

from __future__ import annotations

import argparse

import pytest

from seqnet.cli import build_parser, main


@pytest.mark.parametrize(("argv", "named"), [
    (["serve", "--map", "A", "--map", "B", "--no-auth"], ("--map A", "--map B", "run a second server")),
    (["localize", "--map", "M", "--map", "N", "--query", "q", "--out", "t.csv"], ("--map M", "--map N")),
    (["localize", "--map", "M", "--query", "q1", "--query", "q2.npy", "--out", "t.csv"], ("--query q1",
                                                                                          "--query q2.npy")),
    (["localize", "--map", "M", "--query", "v.mp4", "--positions", "full.csv", "--positions", "half.csv",
      "--out", "t.csv"], ("--positions full.csv", "--positions half.csv")),
    (["eval", "--dataset", "A", "--dataset", "B"], ("--dataset A", "--dataset B")),
    (["eval", "--dataset", "A", "--ks", "1,5", "--ks=1,20"], ("--ks 1,5", "--ks 1,20")),
    (["dataset", "from-images", "r", "q", "--radius", "5", "--radius", "25", "--out", "o"], ("--radius 5",
                                                                                          "--radius 25")),
])
def test_a_one_value_option_given_twice_is_refused_naming_both(argv, named, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "given twice" in err and all(n in err for n in named), err


def test_repeatable_options_repeat_and_a_repeated_equal_value_is_accepted():
    ns = build_parser(["eval"]).parse_args(["eval", "--dataset", "A", "--dataset", "A", "--model", "m1",
                                            "--model", "m2"])
    assert ns.dataset == "A" and ns.model == ["m1", "m2"]
    ns = build_parser(["localize"]).parse_args(["localize", "--map", "M", "--query", "q", "--out", "t.csv"])
    assert (ns.map, ns.query, ns.out) == ("M", "q", "t.csv")


def test_every_one_value_option_of_every_command_refuses_a_second_value():
    """Every ``store`` option of every (sub)command, in argument groups too, is a store-once action."""
    from seqnet.cli import _leaves

    leaves = _leaves(build_parser())
    stores = [(leaf.prog, a.option_strings[0]) for leaf in leaves for a in leaf._actions
              if isinstance(a, argparse._StoreAction) and a.option_strings]
    assert len(leaves) > 15 and len(stores) > 100
    plain = [s for leaf in leaves for a in leaf._actions if type(a) is argparse._StoreAction and a.option_strings
             for s in [(leaf.prog, a.option_strings[0])]]
    assert not plain, plain
