"""Text from files, written out safely: CSV cells that no spreadsheet runs, terminal lines that no name
can take over.

* :func:`csv_cell`: a name read from a file (an image name, a dataset name) that starts with ``=``, ``+``,
  ``-``, ``@``, a tab or a carriage return is prefixed with ``'`` as OWASP advises against CSV (formula)
  injection; the csv module quotes the rest. Numbers are written as numbers.
* :func:`shown`: text for the terminal with every non-printable character (escape sequences, NUL, line
  breaks inside a name) written as its Python escape, so a name cannot move the cursor, clear the
  screen, set the window title or fake another line.
"""

from __future__ import annotations

from typing import Any

FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: Any) -> Any:
    """``value`` for a CSV cell: a string that a spreadsheet would take for a formula gets a leading ``'``."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def shown(text: object) -> str:
    """``str(text)`` with its non-printable characters escaped (``\\x1b``, ``\\x00``, ``\\u2028`` ...)."""
    s = str(text)
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in s)
