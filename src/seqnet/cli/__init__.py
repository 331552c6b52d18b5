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

COMMANDS: dict[str, str] = {  # name -> one-line help; each name's module is <name>_cmd, imported when it runs
    "demo": 'train S_L and S_1 on synthetic data and compare every method',
    "synth": 'write a synthetic dataset (route traversed twice, hard appearance change)',
    "eval": 'evaluate place-recognition methods (Recall@K) on a dataset',
    "train": 'train a SeqNet model (S_L, or S_1 with --seq-len 1 --w 1) with triplet loss',
    "dataset": 'build and check datasets (CSV, UTM image names, seqNet .db files)',
    "describe": 'compute single-image descriptors of an image folder (methods: seqnet describe --help)',
    "benchmark": 'run a benchmark: real data (nordland64) or compute time (timing)',
    "index": 'build a map (ANN index + re-ranking frames) for seqnet eval --index',
    "localize": 'localise a query stream frame by frame (online; latency, confidence)',
    "serve": 'serve the online localiser over HTTP: one map, many sessions (needs seqnet[serve])',
    "experiment": "run one of the paper's supplementary experiments on nordland64",
}


from .runtime import (  # noqa: E402 - the command modules import COMMANDS from here
    add_runtime_options,
    check_no_empty_values,
    classify,
    report_error,
    runtime,
)


class _ArgumentParserError(SeqnetError):
    """A command-line usage error (reported as one line, exit code 2)."""


class _StoreOnce(argparse._StoreAction):
    """argparse's ``store`` (every option of one value, or one list of values), refusing the option given again
    with another value: argparse would keep the last silently (``serve --map A --map B`` serving B alone).
    Options meant to repeat (``--model``, ``--split``) use ``append`` and repeat as before. ``once_hint``: what to
    do instead, said after the refusal."""

    def __init__(self, *args, once_hint: str = "", **kwargs) -> None:  # noqa: ANN002, ANN003 - argparse's
        super().__init__(*args, **kwargs)
        self.once_hint = once_hint

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        given = namespace.__dict__.setdefault("_given_once", {})
        typed = f"{option_string} {' '.join(getattr(self, 'typed', ()))}".strip()
        if self.option_strings and self.dest in given and given[self.dest][1] != values:
            raise argparse.ArgumentError(self, f"given twice ({given[self.dest][0]}, then {typed}): it takes one "
                                         "value, and the second would silently replace the first; "
                                         f"{self.once_hint or 'give it once'}")
        given[self.dest] = (typed, values)
        super().__call__(parser, namespace, values, option_string)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors raise instead of printing the usage and exiting,
    that never accepts abbreviations ("--shortlist" must not silently mean "--shortlist-model"), and whose
    one-value options refuse a second value (:class:`_StoreOnce`, for every command and argument group)."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003 - argparse's signature
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        raise _ArgumentParserError(f"{self.prog}: error: {message} (see `{self.prog} --help`)")

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> object:
        """As argparse's; a :class:`_StoreOnce` keeps the strings as typed (``typed``), to name them if repeated."""
        if isinstance(action, _StoreOnce):
            action.typed = list(arg_strings)
        return super()._get_values(action, arg_strings)

    def parse_known_args(self, args=None, namespace=None):  # noqa: ANN001, ANN201 - argparse's signature
        """As argparse's, recording the deepest (sub)command parsed in ``namespace._command_prog``."""
        namespace = argparse.Namespace() if namespace is None else namespace
        namespace._command_prog = self.prog  # a subcommand's parser runs after its parent's: it overwrites
        namespace._given_once = {}  # the one-value options given so far (:class:`_StoreOnce`), this parser's
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None):  # noqa: ANN001, ANN201 - argparse's signature
        """As argparse's; an unknown option is an error of the (sub)command it was given to, ``seqnet <command>``
        (argparse names the top-level parser, ``seqnet``, for these)."""
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            prog = getattr(parsed, "_command_prog", self.prog)
            raise _ArgumentParserError(f"{prog}: error: unrecognized arguments: {' '.join(extras)} "
                                       f"(see `{prog} --help`)")
        return parsed


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with one sub-parser per command (runtime options on every one). Only the command
    named in ``argv`` is built in full (its module imported: torch and the rest load only for a command
    that runs); the others are one-line entries, enough for ``seqnet --help``. Without ``argv``: all in full."""
    parser = _Parser(prog="seqnet", description="Sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).")
    parser.add_argument("--version", action="version", version=f"seqnet {__version__}")
    add_runtime_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = set(COMMANDS) if argv is None else {_command_of(argv)}
    for name, summary in COMMANDS.items():
        if name in wanted:
            importlib.import_module(f"{__name__}.{name}_cmd").register(sub)
        else:
            sub.add_parser(name, help=summary)
    for leaf in _leaves(parser):
        add_runtime_options(leaf, top=False)
    return parser


def _command_of(argv: Sequence[str]) -> str | None:
    """The command named in ``argv`` (the first word that is not a runtime option or its value)."""
    it = iter(argv)
    for token in it:
        if token == "--threads":
            next(it, None)
        elif not token.startswith("-"):
            return token
    return None


def _leaves(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers that run a command (sub-parsers without sub-parsers of their own)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [parser]
    return [leaf for a in subs for p in dict.fromkeys(a.choices.values()) for leaf in _leaves(p)]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 2 bad input, 1 environment failure, 130 interrupted)."""
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        args = build_parser(argv).parse_args(argv)
    except _ArgumentParserError as e:
        return report_error(None, e)
    try:
        check_no_empty_values(args)
        if isinstance(getattr(args, "device", None), str):  # a device that is not there: refused before any work
            from ..core.devices import check_device

            check_device(args.device)
        with runtime(args):
            return int(args.func(args) or 0)
    except (SeqnetError, MemoryError, KeyboardInterrupt) as e:
        return report_error(args.command, e)
    except Exception as e:  # noqa: BLE001 - the one error boundary: an OS, library or internal failure, one line
        return report_error(args.command, classify(e), trace=e if args.verbose else None)


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
