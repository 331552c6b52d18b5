"""Command-line interface: ``seqnet <command> ...``.

Each command lives in its own module of this package and only parses arguments and calls one
stage. This module is the one error boundary: every :class:`seqnet.core.errors.SeqnetError` and every
OS failure becomes one line on stderr (progress bars cleared first, third-party warnings held
back) with exit code 2 for bad input and 1 for a failing environment (disk full, read-only file
system, permission, a lock held by another process), never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from .._version import __version__
from ..core.errors import SeqnetError
from .runtime import add_runtime_options, check_no_empty_values, is_allocation_error, one_line, report_error, runtime

COMMANDS = ("demo", "synth", "eval", "train", "dataset", "describe", "benchmark", "index", "localize",
            "experiment")


class _ArgumentParserError(SeqnetError):
    """A command-line usage error (reported as one line, exit code 2)."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors raise instead of printing the usage and exiting,
    and that never accepts abbreviations ("--shortlist" must not silently mean "--shortlist-model")."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003 - argparse's signature
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        raise _ArgumentParserError(f"{self.prog}: error: {message} (see `{self.prog} --help`)")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-parser per command module (runtime options on every one)."""
    parser = _Parser(prog="seqnet", description="Sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).")
    parser.add_argument("--version", action="version", version=f"seqnet {__version__}")
    add_runtime_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}_cmd").register(sub)
    for leaf in _leaves(parser):
        add_runtime_options(leaf, top=False)
    return parser


def _leaves(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers that run a command (sub-parsers without sub-parsers of their own)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [parser]
    return [leaf for a in subs for p in dict.fromkeys(a.choices.values()) for leaf in _leaves(p)]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 2 bad input, 1 environment failure, 130 interrupted)."""
    try:
        args = build_parser().parse_args(argv)
    except _ArgumentParserError as e:
        return report_error(None, e)
    try:
        check_no_empty_values(args)
        with runtime(args):
            return int(args.func(args) or 0)
    except (SeqnetError, OSError, MemoryError, KeyboardInterrupt) as e:
        return report_error(args.command, e)
    except RuntimeError as e:  # torch's allocators report running out of memory as a RuntimeError
        if not is_allocation_error(e):
            raise
        return report_error(args.command, MemoryError(one_line(e)))


def entry_point() -> None:
    """Console-script entry point: a file size limit fails the write (EFBIG, exit 1) instead of killing the
    process (SIGXFSZ); a reader that went away (``seqnet … | head``) is exit 1, with nothing printed after."""
    import signal

    if hasattr(signal, "SIGXFSZ"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        code = main()
        sys.stdout.flush()
    except BrokenPipeError:
        code = 1
    if code == 1 or not _stdout_alive():
        with contextlib.suppress(OSError):  # no "Exception ignored" on a closed pipe at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    sys.exit(code)


def _stdout_alive() -> bool:
    try:
        sys.stdout.flush()
        return True
    except (BrokenPipeError, ValueError):
        return False
