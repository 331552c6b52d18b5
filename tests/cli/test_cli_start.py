"""A fast start: ``import seqnet``, ``seqnet --help`` / ``--version`` / an unknown command, and a command's
``--help`` and argument errors import no torch (0.2-0.5 s against 1.5-2.5 s before on this machine; a command
imports it when it runs: :mod:`seqnet.core.lazy`)."""

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


LIGHT_COMMANDS = ("eval", "train", "localize", "index", "synth", "describe", "dataset", "demo", "benchmark",
                  "experiment", "serve")


@pytest.mark.parametrize(("argv", "code"), [(["--help"], 0), (["--version"], 0), (["nosuch"], 2), ([], 2),
                                            *[([c, "--help"], 0) for c in LIGHT_COMMANDS],
                                            *[([c, "--no-such-option"], 2) for c in LIGHT_COMMANDS],
                                            (["localize", "--precision", "float8"], 2),
                                            (["eval", "--dataset", "NOSUCH_DIR", "--method", "nosuch"], 2),
                                            (["localize", "--dataset", "D", "--method", "x", "--out", "t.csv"], 2)])
def test_the_top_level_imports_no_torch(argv, code):
    p = subprocess.run([sys.executable, "-c", PROBE.format(argv=argv)], capture_output=True, text=True, timeout=60)
    assert p.stdout.split() == [str(code), "False"], (p.stdout, p.stderr[-2000:])


def test_the_public_api_loads_on_first_use():
    p = subprocess.run([sys.executable, "-c", "import sys, seqnet; a = 'torch' in sys.modules; "
                        "from seqnet import SeqNet, knn; print(a, 'torch' in sys.modules, SeqNet.__name__, "
                        "sorted(set(seqnet.__all__) - set(dir(seqnet))))"], capture_output=True, text=True, timeout=60)
    assert p.stdout.split() == ["False", "True", "SeqNet", "[]"], (p.stdout, p.stderr[-2000:])


def test_the_subpackages_are_attributes_after_import_seqnet():
    """``import seqnet; seqnet.train.train(...)`` was an AttributeError (only ``from seqnet.train import train``
    worked); every subpackage of the layer order is an attribute, loaded on first use."""
    from pathlib import Path

    import seqnet

    src = Path(seqnet.__file__).parent
    packages = {p.name for p in src.iterdir() if (p / "__init__.py").is_file()} - {"cli", "__pycache__"}
    assert packages == set(seqnet._PACKAGES) and set(seqnet._PACKAGES) <= set(dir(seqnet))
    assert seqnet.train.train is __import__("seqnet.train", fromlist=["train"]).train
    with pytest.raises(AttributeError, match="no attribute 'nosuch'"):
        seqnet.nosuch  # noqa: B018


def test_every_command_is_listed_and_builds():
    from seqnet.cli import COMMANDS, build_parser

    parser = build_parser()  # every command in full
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == list(COMMANDS)
    assert all(sub.choices[n].description or sub.choices[n]._actions for n in COMMANDS)



def test_a_lazy_module_loads_on_first_read_and_then_is_the_module():
    import types

    from seqnet.core.lazy import LazyModule, lazy_module, no_grad

    mod = LazyModule("json")
    assert "dumps" not in mod.__dict__
    assert mod.dumps([1]) == "[1]" and "dumps" in mod.__dict__  # copied in: later reads skip __getattr__
    assert lazy_module("sys") is sys and isinstance(lazy_module("nosuch_mod_xyz"), types.ModuleType)
    with pytest.raises(ModuleNotFoundError):
        getattr(lazy_module("nosuch_mod_xyz"), "anything")  # noqa: B009 - the read is the test

    import torch

    @no_grad
    def grad_on() -> bool:
        return torch.is_grad_enabled()

    assert torch.is_grad_enabled() and not grad_on() and grad_on.__name__ == "grad_on"
    with pytest.raises(TypeError, match="generator"):
        no_grad(lambda: (yield))


def test_a_commands_threads_reach_torch_loaded_during_the_command():
    """Without torch loaded, the runtime sets its threads through OMP_NUM_THREADS (read when torch loads), then
    restores the variable."""
    code = ("import argparse, os, sys\n"
            "from seqnet.cli.runtime import runtime\n"
            "args = argparse.Namespace(verbose=False, quiet=True, threads=1, progress=None)\n"
            "with runtime(args):\n"
            "    import torch\n"
            "    inside = torch.get_num_threads()\n"
            "print(inside, os.environ.get('OMP_NUM_THREADS'))\n")
    env = {k: v for k, v in __import__("os").environ.items() if k != "OMP_NUM_THREADS"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
    assert p.stdout.split() == ["1", "None"], (p.stdout, p.stderr[-2000:])
