"""What ``seqnet eval`` writes, and how (all three routes: a dataset, a map, a distance matrix).

* ``--out DIR``: ``results.json``, ``pr_curve.png`` (``figures``), ``report.html`` (``report``) and a
  ``--per-query`` (or ``--json``) output named directly in ``DIR`` are one set, written by
  :func:`seqnet.security.folders.update_folder` under the lock of ``DIR``: a kill at any moment leaves the
  old set whole or the new one whole; a user's other files in ``DIR`` are carried over untouched; a file of
  an earlier set that this run does not write (its ``report.html``, when this run makes none) leaves with
  that set, when seqnet wrote it.
* An output name in ``DIR`` that holds a file seqnet did not write is refused before any work, unless
  ``overwrite``; so is an existing ``--per-query`` or ``--json`` file elsewhere that is not seqnet's
  (:func:`seqnet.eval.results.check_per_query`; a results JSON is recognised by its ``methods`` and
  ``config``).
* Outside ``DIR`` (or without it) ``--per-query`` and ``--json`` are written on their own, atomically, before
  the set; without ``DIR`` nothing else is written (no temporary folder: the results stay in memory).
* An error while the set is written names the user's path (``DIR/results.json``), never the temporary folder.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, OutputError, SeqnetError
from ..core.stage import Written
from ..security.dirs import remove_dead_temps
from ..security.files import TEMP_MARK, TEMP_SUFFIX, temp_prefix, write_json_atomic, write_text_atomic
from ..security.folders import check_outputs, update_folder
from ..security.jsonfile import read_json
from ..security.locks import locked
from ..security.ownership import MANIFEST
from .notices import few_queries_note
from .results import check_per_query, per_query_format, per_query_text

RESULTS, PR_CURVE, REPORT = "results.json", "pr_curve.png", "report.html"
EVAL_SET = (RESULTS, PR_CURVE, REPORT)  # what an evaluation writes in --out DIR (besides a --per-query there)
WHAT = "evaluation results"
ONE_METHOD_FORMATS = (".txt", "")  # MSLS predictions and a VPR-methods-evaluation folder: one method each


@dataclasses.dataclass(frozen=True)
class EvalOutputs:
    """Where one evaluation writes: the folder ``out`` (None: none), the ``per_query`` output, the ``json`` copy of
    the results, ``pr_curve.png`` (``figures``), ``report.html`` (``report``: a
    :class:`seqnet.report.html.ReportConfig`); ``overwrite`` replaces outputs seqnet did not write."""

    out: Path | None = None
    per_query: Path | None = None
    json: Path | None = None
    figures: bool = False
    report: Any = None
    overwrite: bool = False

    def __post_init__(self) -> None:
        for key in ("out", "per_query", "json"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, Path(getattr(self, key)))
        if self.report is not None and self.out is None:
            raise ConfigError("--report writes report.html beside results.json: give --out DIR")
        if self.per_query is not None:
            per_query_format(self.per_query)
        if self.per_query is not None and self.json is not None and _real(self.per_query) == _real(self.json):
            raise ConfigError(f"--per-query and --json name the same file {self.json}; give each its own")
        self.in_out(self.per_query, "--per-query")
        self.in_out(self.json, "--json")

    def in_out(self, path: Path | None, flag: str) -> str | None:
        """The name of ``path`` when it lies directly in ``out`` (it joins the set), None when it lies outside;
        refused deeper inside ``out``, as ``out`` itself, or as a file of the set (``--json DIR/results.json``
        is the set's results.json)."""
        if path is None or self.out is None:
            return None
        real, root = _real(path), Path(os.path.realpath(self.out))
        if real.parent == root:
            if flag == "--json" and real.name == RESULTS:
                return RESULTS
            if real.name in (*EVAL_SET, MANIFEST) or (TEMP_MARK in real.name and real.name.endswith(TEMP_SUFFIX)):
                raise ConfigError(f"{flag} {path} is a file the evaluation writes itself in {self.out}; choose "
                                  "another name")
            return real.name
        if real == root:
            raise ConfigError(f"{flag} {path} is the --out folder itself; name a file in it or outside it")
        if root in real.parents:
            raise ConfigError(f"{flag} {path} lies inside --out {self.out} but not directly in it; name a file in "
                              f"{self.out} itself (it is then written with the results) or outside it")
        return None

    def names(self) -> list[str]:
        """The top-level names this run writes in ``out``."""
        inside = [n for n in (self.in_out(self.per_query, "--per-query"), self.in_out(self.json, "--json")) if n]
        return list(dict.fromkeys([RESULTS, *([PR_CURVE] if self.figures else []),
                                   *([REPORT] if self.report is not None else []), *inside]))

    def check(self, methods: Sequence[str] | None = None) -> None:
        """Refuse, before any work, what this run could not write: an output seqnet did not write (unless
        ``overwrite``), a one-method per-query format for several ``methods``."""
        self.check_methods(methods)
        if self.out is not None:
            check_outputs(self.out, self.names(), WHAT, self.overwrite)
        if self.per_query is not None and self.in_out(self.per_query, "--per-query") is None:
            check_per_query(self.per_query, self.overwrite)
        if self.json is not None and self.in_out(self.json, "--json") is None:
            check_results_json(self.json, self.overwrite)

    def check_methods(self, methods: Sequence[str] | None) -> None:
        """A per-query format that holds one method's predictions is refused for several ``methods`` (None: not
        known yet)."""
        if self.per_query is not None and methods is not None and len(methods) != 1 and \
                per_query_format(self.per_query) in ONE_METHOD_FORMATS:
            kind = "an MSLS predictions file" if self.per_query.suffix else \
                "a VPR-methods-evaluation predictions folder"
            raise ConfigError(f"--per-query {self.per_query}: {kind} holds one method, got {len(methods)} "
                              f"({', '.join(methods)}); hint: --method M")

    @contextlib.contextmanager
    def session(self, methods: Sequence[str] | None = None) -> Iterator[EvalOutputs]:
        """The block of one evaluation: ``out`` locked (a second evaluation into it is refused, exit 1), what a
        killed run left there removed, and :meth:`check` done, before any work."""
        if self.out is None:
            self.check(methods)
            yield self
            return
        with locked(self.out):
            remove_dead_temps(self.out / n for n in (*EVAL_SET, *self.names()))
            self.check(methods)
            yield self

    def write(self, ev: Any) -> Written:
        """Write the outputs of the evaluation ``ev`` (inside :meth:`session`): those outside ``out`` first, then
        the set in ``out`` at once; returns the results file (``out/results.json``, else the ``--json`` file,
        else no path) and the results. An R@1 over few queries is noted in the results (``"few_queries"``)."""
        note = few_queries_note(ev.results)
        if note:
            ev.results["few_queries"] = note
        if self.per_query is not None and self.in_out(self.per_query, "--per-query") is None:
            from .results import write_per_query

            write_per_query(ev, self.per_query)
        if self.json is not None and self.in_out(self.json, "--json") is None:
            write_json_atomic(self.json, ev.results)
        if self.out is None:
            return Written(self.json or Path(), ev.results)
        try:
            update_folder(self.out, lambda tmp: self._fill(ev, tmp), WHAT, self.overwrite, drop=EVAL_SET)
        except OSError as e:
            e.filename, e.filename2 = self._named(e.filename), self._named(e.filename2)
            raise
        except SeqnetError as e:
            e.args = (self._named(str(e)),)
            raise
        return Written(self.out / RESULTS, ev.results)

    def _fill(self, ev: Any, tmp: Path) -> list[Path]:
        """The set, written in the temporary folder ``tmp``: the files written."""
        res = ev.results
        files = [write_json_atomic(tmp / RESULTS, res)]
        if self.figures:
            from ..report.tables import plot_pr_curves

            files.append(plot_pr_curves(res["methods"], tmp / PR_CURVE, title=res["config"]["dataset"]))
        if self.report is not None:
            from ..report.html import write_html_report

            files.append(write_html_report(ev, ev.dataset, tmp / REPORT, self.report))
        name = self.in_out(self.per_query, "--per-query")
        if name is not None:
            files += _write_text(tmp / name, per_query_text(ev, tmp / name))
        name = self.in_out(self.json, "--json")
        if name is not None and name != RESULTS:
            files.append(write_json_atomic(tmp / name, res))
        return files

    def _named(self, text: Any) -> Any:
        """``text`` (a message or a path) naming ``out`` where it named the temporary folder of its new version."""
        if not isinstance(text, str) or self.out is None:
            return text
        real = Path(os.path.realpath(self.out))
        tmp = re.escape(str(real.parent / temp_prefix(real.name))) + r"[^/\s]*?" + re.escape(TEMP_SUFFIX)
        return re.sub(tmp, lambda _: str(self.out), text)


def _real(path: Path) -> Path:
    """``path`` with its folder resolved (the last name kept: a link there is replaced, never followed)."""
    return Path(os.path.realpath(path.parent)) / path.name


def _write_text(path: Path, text: str | dict[str, str]) -> list[Path]:
    """A file, or a folder of files (name: text): the files written."""
    if isinstance(text, str):
        return [write_text_atomic(path, text)]
    path.mkdir()
    return [write_text_atomic(path / name, t) for name, t in text.items()]


def check_results_json(path: Path, overwrite: bool = False) -> None:
    """Refuse (:class:`OutputError`) to replace an existing ``--json`` file that is not a results JSON seqnet wrote
    (an object with ``methods`` and ``config``; never a link or a special file), unless ``overwrite``."""
    if overwrite or not (path.exists() or path.is_symlink()):
        return
    try:
        value = None if path.is_symlink() else read_json(path, "results JSON", OutputError, limit=256 << 20)
    except (OSError, OutputError):
        value = None
    ours = isinstance(value, dict) and isinstance(value.get("methods"), dict) and isinstance(value.get("config"), dict)
    if not ours:
        raise OutputError(f"{path} exists and is not a results JSON written by seqnet eval; move it away, choose "
                          "another --json, or pass --overwrite")
