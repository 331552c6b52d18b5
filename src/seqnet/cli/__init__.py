"""Command-line interface: ``seqnet <command> ...``.

Each command lives in its own module of this package and only parses arguments and calls the
library. Every :class:`seqnet.errors.SeqnetError` (and bad-file OS errors) becomes one line on
stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import sys
from collections.abc import Iterator, Sequence
from typing import NoReturn

from .._version import __version__
from ..errors import SeqnetError

COMMANDS = ("demo", "synth", "eval", "train", "dataset", "describe", "benchmark")


class _ArgumentParserError(SeqnetError):
    """A command-line usage error (reported as one line, exit code 2)."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors raise instead of printing the usage and exiting."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003 - argparse's signature
        kwargs.setdefault("allow_abbrev", False)  # "--shortlist" must not silently mean "--shortlist-model"
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        raise _ArgumentParserError(f"{self.prog}: error: {message} (see `{self.prog} --help`)")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-parser per command module."""
    parser = _Parser(
        prog="seqnet", description="Sequence-based visual place recognition (SeqNet, SeqMatch, HVPR)."
    )
    parser.add_argument("--version", action="version", version=f"seqnet {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser.add_argument("-q", "--quiet", action="store_true", help="only log warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}_cmd")
        except ModuleNotFoundError as e:  # a command of an optional part that is not installed
            if e.name != f"{__name__}.{name}_cmd":
                raise
            continue
        module.register(sub)
    return parser


class _StderrHandler(logging.StreamHandler):
    """Log handler that writes to whatever ``sys.stderr`` is at the time (pytest's capsys swaps it)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property  # type: ignore[override]
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # the base class assigns it; always follow sys.stderr instead
        pass


@contextlib.contextmanager
def _logging_to_stderr(level: int) -> Iterator[None]:
    """Log seqnet messages to stderr at ``level`` while a command runs; restore the logger after."""
    log = logging.getLogger("seqnet")
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    old_level = log.level
    log.addHandler(handler)
    log.setLevel(level)
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.setLevel(old_level)


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 2 user error).

    Every user error is reported as exactly one line on stderr, without a traceback.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _ArgumentParserError as e:
        print(_one_line(e), file=sys.stderr)
        return 2
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    try:
        with _logging_to_stderr(level):
            return int(args.func(args) or 0)
    except SeqnetError as e:
        print(f"seqnet {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError, NotADirectoryError) as e:
        print(f"seqnet {args.command}: error: {_one_line(e.strerror or e)}: {e.filename}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seqnet {args.command}: interrupted", file=sys.stderr)
        return 130


def entry_point() -> None:
    """Console-script entry point."""
    sys.exit(main())
