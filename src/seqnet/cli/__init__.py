"""Command-line interface: ``seqnet <command> ...``.

Each command lives in its own module of this package and only parses arguments and calls the
library. Every :class:`seqnet.errors.SeqnetError` (and bad-file OS errors) becomes one line on
stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Sequence

from .. import __version__
from ..errors import SeqnetError

COMMANDS = ("demo", "synth", "eval", "train", "dataset", "describe", "benchmark")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-parser per command module."""
    parser = argparse.ArgumentParser(
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


class _ArgumentParserError(SeqnetError):
    pass


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 2 user error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
    try:
        return int(args.func(args) or 0)
    except SeqnetError as e:
        print(f"seqnet {args.command}: error: {e}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError, NotADirectoryError) as e:
        print(f"seqnet {args.command}: error: {e.strerror}: {e.filename}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seqnet {args.command}: interrupted", file=sys.stderr)
        return 130


def entry_point() -> None:
    """Console-script entry point."""
    sys.exit(main())
