"""Matching image names of one list to another (CSV rows to descriptors, images to CSV rows).

Names match exactly, else by file name (last path component), else by file name without extension, else the
same in Unicode NFC form (macOS NFD file names against NFC names typed in a CSV), else as numbers (a spreadsheet
stripped the leading zeros of ``0000000042``: said in one line). A name
matching two of the other list, and two names matching the same one, are errors naming both (and the CSV
lines, for names read from a CSV: :class:`CsvNames`); a name matching none is an error saying which side lacks
it, with a hint when the names differ only in case.
"""

from __future__ import annotations

import unicodedata
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ...core.errors import DatasetError
from ...core.log import counted, logger


class CsvNames(list):
    """Image names read from a CSV file (a ``list[str]``) that remember the file and the line of each name,
    so a message about a name can point at its line."""

    def __init__(self, names: Sequence[str], path: str | Path, lines: Sequence[int]) -> None:
        super().__init__(names)
        self.path, self.lines = str(path), list(lines)


def _basename(s: str) -> str:
    return s.replace("\\", "/").rsplit("/", 1)[-1]


def _stem(s: str) -> str:
    return _basename(s).rsplit(".", 1)[0]


def _nfc(key: Callable[[str], str]) -> Callable[[str], str]:
    """``key`` of the name in Unicode NFC form: macOS file names are often NFD (``o`` + a combining diaeresis),
    names typed in a CSV NFC (``ö``); they print alike but differ."""
    return lambda s: unicodedata.normalize("NFC", key(s))


def _by_value(s: str) -> str:
    """The file name without extension, a number's without its leading zeros (``0000000042.png`` → ``42``: a
    spreadsheet stores the name ``0000000042`` as the number 42)."""
    stem = _stem(s)
    return str(int(stem)) if stem.isascii() and stem.isdigit() and len(stem) <= 30 else stem


NAME_KEYS: tuple[Callable[[str], str], ...] = (lambda s: s, _basename, _stem,  # exact, file name, stem, then in NFC
                                                _nfc(lambda s: s), _nfc(_basename), _nfc(_stem), _by_value)
MATCHED = ("names are matched exactly, then by file name, then without extension (each also in Unicode NFC form), "
           "then as numbers")


def _shown(names: Sequence[str], i: int) -> str:
    """``'x.png'``, and ``(line 6)`` when ``names`` were read from a CSV."""
    lines = getattr(names, "lines", None)
    return f"{names[i]!r}" + (f" (line {lines[i]})" if lines is not None else "")


def _plural(names: Sequence[str], wanted: bool) -> str:
    """What several names of ``names`` are, in messages: rows of a CSV, else images (wanted) or descriptors."""
    if isinstance(names, CsvNames):
        return f"rows of {names.path}"
    return "images" if wanted else "descriptors"


def warn_reordered(rows: np.ndarray, names: Sequence[str], csv: CsvNames, source: str, hint: str) -> bool:
    """Warn (and return True) when ``csv`` lists ``names`` (a traverse's images, in their order; ``rows[i]``: the
    row of ``csv`` of image ``i``, [N] int) in another order; ``source`` names where the order comes from."""
    back = np.flatnonzero(np.diff(rows) < 0)
    if not back.size or sorted_as_text([names[j] for j in np.argsort(rows, kind="stable")]):
        return False  # a CSV sorted as text (ls, sorted(), a spreadsheet's sort) says nothing of the route's order
    i = int(back[0]) + 1
    logger.warning("%s lists the images in another order than %s (image %d, %r, is on line %d, after line %d "
                   "(image %d, %r)); the traverse follows %s, the CSV only places the images; hint: %s", csv.path,
                   source, i, names[i], csv.lines[rows[i]], csv.lines[rows[i - 1]], i - 1, names[i - 1], source,
                   hint)
    return True


def sorted_as_text(names: Sequence[str]) -> bool:
    """Whether ``names`` are in plain text order (``img1, img10, img2``), case-sensitive or not."""
    return list(names) == sorted(names) or list(names) == sorted(names, key=str.lower)


def match_names(wanted: list[str], available: list[str], what: str) -> np.ndarray:
    """Index into ``available`` of each name in ``wanted``, ``[len(wanted)]`` int64.

    Names match exactly, else by file name (last path component), else by file name without
    extension. Raises :class:`DatasetError` naming the first name that does not match, that matches two
    of ``available``, or that is matched by two of ``wanted`` (``x`` in a CSV for both ``x.png`` and
    ``x.jpg``), instead of silently taking one of them.
    """
    for key in NAME_KEYS:
        table: dict[str, list[int]] = {}
        for i, n in enumerate(available):
            table.setdefault(key(n), []).append(i)
        hits = [table.get(key(n), []) for n in wanted]
        if all(hits):
            _refuse_ambiguous(wanted, available, hits, what)
            odd = None if key is not _by_value else \
                next((i for i, h in enumerate(hits) if _stem(wanted[i]) != _stem(available[h[0]])), None)
            if odd is not None:
                logger.info("%s: names matched as numbers (%r and %r): leading zeros stripped (a spreadsheet?)",
                            what, wanted[odd], available[hits[odd][0]])
            return np.asarray([h[0] for h in hits], dtype=np.int64)
    raise _missing(wanted, available, hits, what)


def _refuse_ambiguous(wanted: list[str], available: list[str], hits: list[list[int]], what: str) -> None:
    bad = next((i for i, h in enumerate(hits) if len(h) > 1), None)
    if bad is not None:
        first, second = hits[bad][:2]
        raise DatasetError(f"{what}: image name {_shown(wanted, bad)} matches two {_plural(available, False)} "
                           f"({_shown(available, first)} and {_shown(available, second)}); hint: give names that "
                           "identify one image each")
    seen: dict[int, int] = {}
    for i, h in enumerate(hits):
        j = h[0]
        if j in seen:
            raise DatasetError(f"{what}: the name {_shown(available, j)} matches two {_plural(wanted, True)}, "
                               f"{_shown(wanted, seen[j])} and {_shown(wanted, i)} ({MATCHED}); hint: give names "
                               "that identify one image each, with their extension")
        seen[j] = i


def _missing(wanted: list[str], available: list[str], hits: list[list[int]], what: str) -> DatasetError:
    missing = [i for i, h in enumerate(hits) if not h]
    first = wanted[missing[0]]
    lacks = f"no row in {available.path}" if isinstance(available, CsvNames) else "no descriptor"
    others = f"the names in {available.path}" if isinstance(available, CsvNames) else "descriptor names"
    looks = f"{others} look like {available[0]!r}" if available else f"there are no {others}"
    folded = {key(n).casefold(): n for key in NAME_KEYS for n in available}
    twin = next((folded[key(first).casefold()] for key in NAME_KEYS if key(first).casefold() in folded), None)
    case = (f"; the names differ only in case ({first!r} and {twin!r}): names are matched case-sensitively"
            if twin is not None else "")
    return DatasetError(f"{what}: {len(missing)} of {counted(len(wanted), 'image name')} "
                        f"{'has' if len(missing) == 1 else 'have'} {lacks} (first: {_shown(wanted, missing[0])}; "
                        f"{looks}){case}; hint: {MATCHED}")
