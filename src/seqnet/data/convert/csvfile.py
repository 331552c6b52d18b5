"""Positions CSV files: an image-name column, position columns, an optional sequence column.

The header names an image column (one of :data:`NAME_COLUMNS`) and either easting/northing columns
(metres), lat/lon columns (unit ``degrees``) or a frame column (frames); fields are separated by ``,``, ``;``
or a tab (:func:`seqnet.data.readers.field_separator`, as the positives reader), and a UTF-8 byte-order mark is
dropped. An optional sequence column gives sequence bounds: each run of consecutive rows with the same key
is one sequence (:func:`sequence_bounds`, which warns when a key comes back after other keys' rows, or when
every sequence is shorter than the default sequence length).
"""

from __future__ import annotations

import csv
import dataclasses
import io
from pathlib import Path

import numpy as np

from ...core.errors import DatasetError
from ...core.log import counted, logger
from ...security.limits import POSITION_MAX
from ..readers import check_names, field_separator, read_text
from ..utm import check_latlon
from .names import CsvNames

NAME_COLUMNS = ("name", "image", "image_name", "filename", "file", "path", "key", "image_key")
EAST_COLUMNS = ("easting", "east", "utm_east", "utm_easting", "x")
NORTH_COLUMNS = ("northing", "north", "utm_north", "utm_northing", "y")
LAT_COLUMNS = ("lat", "latitude")
LON_COLUMNS = ("lon", "lng", "long", "longitude")  # "long": Google Takeout, many loggers
FRAME_COLUMNS = ("frame", "frame_number", "frame_id", "frame_index")
SEQUENCE_COLUMNS = ("sequence", "sequence_key", "seq", "seq_key")
ENCODING_HINT = "hint: text in another encoding (Windows-1252, Latin-1)? Save it as UTF-8"
SHORT_SEQUENCE = 5  # the default sequence length L (seqnet.sequence.windows.DEFAULT_SEQ_LEN; a test keeps them equal)


def read_csv_rows(path: str | Path, quiet: bool = False) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The lower-cased header and the non-blank data rows ``(line number, fields)`` of a UTF-8 CSV file
    (fields separated by ``,``, ``;`` or a tab, as its first line is). ``#`` comment lines before the header
    are left out (said in one line, unless ``quiet``); the header repeated among the rows (two files
    concatenated) is an error."""
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"CSV file not found: {p}")
    try:
        text = read_text(p, "CSV file")  # a FIFO or device is refused, never read; a byte-order mark dropped
    except DatasetError as e:
        if "not UTF-8" not in str(e):
            raise
        raise DatasetError(f"{e}; {ENCODING_HINT}") from e
    first = next((line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")), "")
    try:
        reader = csv.reader(io.StringIO(text, newline=""), delimiter=field_separator(first) or ",")
        rows = [(n, r) for n, r in enumerate(reader, start=1)]
    except csv.Error as e:
        raise DatasetError(f"{p}: not a valid CSV file ({' '.join(str(e).split())[:200]})") from e
    rows = [(n, r) for n, r in rows if r and any(c.strip() for c in r)]
    comments = next((i for i, (_, r) in enumerate(rows) if not r[0].lstrip().startswith("#")), len(rows))
    if comments and not quiet:
        logger.info("%s: left out %s ('#') before the header", p, counted(comments, "comment line"))
    rows = rows[comments:]
    if len(rows) < 2:
        raise DatasetError(f"{p}: needs a header row and at least one data row")
    header = [h.strip().lower() for h in rows[0][1]]
    again = next((n for n, r in rows[1:] if [h.strip().lower() for h in r] == header), None)
    if again is not None:
        raise DatasetError(f"{p}, line {again}: the header repeats (two files concatenated?); hint: remove line "
                           f"{again}, and check that the rows after it belong to this traverse")
    return header, rows[1:]


@dataclasses.dataclass
class PositionsTable:
    """A positions CSV as read: names (with their lines), ``positions [N, P]``, their unit, and the sequence
    column's keys (None without one) and name."""

    names: CsvNames
    positions: np.ndarray
    unit: str
    keys: list[str] | None
    column: str | None


KIND_COLUMNS = {"metres": ("east", "north"), "degrees": ("lat", "lon"), "frames": ("frame",)}  # in default order


def position_kinds(path: str | Path) -> dict[str, list[str]]:
    """The kinds of positions a positions CSV has (``metres``, ``degrees``, ``frames``, in :data:`KIND_COLUMNS`'s
    order: the first is used by default), each with its columns as the header names them."""
    p = Path(path)
    header, _ = read_csv_rows(p, quiet=True)  # said when the rows are read
    return _kinds(header, _find_columns(header, p))


def _kinds(header: list[str], col: dict[str, int]) -> dict[str, list[str]]:
    """The kinds of positions of a header whose columns are ``col`` (:func:`position_kinds`)."""
    return {k: [header[col[c]] for c in cs] for k, cs in KIND_COLUMNS.items() if all(c in col for c in cs)}


def agreed_kinds(paths: tuple[str | Path, str | Path]) -> tuple[str, str]:
    """The kind of positions to read from each of two positions CSVs (reference, query): the first kind both have
    (a CSV with lat, lon and x, y against one with lat, lon only: lat, lon), else each its default. A CSV with
    two kinds of position columns (metres and degrees), or read in another than its default kind, is said."""
    kinds = [position_kinds(p) for p in paths]
    common = [k for k in KIND_COLUMNS if k in kinds[0] and k in kinds[1]]
    chosen = [common[0] if common else next(iter(ks)) for ks in kinds]
    for i, (p, ks, k) in enumerate(zip(paths, kinds, chosen, strict=True)):
        if k != next(iter(ks)) or ("metres" in ks and "degrees" in ks):
            why = (f"the kind {paths[1 - i]} has" if len(kinds[1 - i]) == 1 and k in kinds[1 - i] else
                   "both CSVs have them" if k in kinds[1 - i] else f"{paths[1 - i]} has no kind in common")
            _say_kinds(p, ks, k, why)
    return chosen[0], chosen[1]


def _say_kinds(p: str | Path, kinds: dict[str, list[str]], used: str, why: str) -> None:
    has = " and ".join(f"{', '.join(cs)} ({u})" for u, cs in kinds.items())
    logger.info("%s has position columns %s: using %s (%s)", p, has, ", ".join(kinds[used]), why)


def read_positions_table(path: str | Path, kind: str | None = None) -> PositionsTable:
    """Read a positions CSV (module docstring), its positions of ``kind`` (``metres``, ``degrees``, ``frames``:
    :func:`agreed_kinds`; by default the first it has). A row with too few fields, a non-numeric position or a
    repeated image name is an error naming its line; lat/lon are checked in range
    (:func:`seqnet.data.utm.latlon_pair` makes them metres)."""
    p = Path(path)
    header, rows = read_csv_rows(p)
    col = _find_columns(header, p)
    kinds = _kinds(header, col)
    if kind is not None and kind not in kinds:
        raise DatasetError(f"{p}: header {header} has no {kind} position columns (it has {', '.join(kinds)})")
    if kind is None and "metres" in kinds and "degrees" in kinds:
        _say_kinds(p, kinds, next(iter(kinds)), "the first kind")
    kind = kind or next(iter(kinds))
    col = {k: i for k, i in col.items() if k in ("name", "seq") or k in KIND_COLUMNS[kind]}
    for line, r in rows:
        if len(r) <= max(col.values()):
            raise DatasetError(f"{p}, line {line}: {len(r)} fields, but the header has {len(header)} "
                               f"(columns {header})")
    names = CsvNames([r[col["name"]].strip() for _, r in rows], p, [line for line, _ in rows])
    first_line: dict[str, int] = {}
    for line, name in zip(names.lines, names, strict=True):
        if name in first_line:
            raise DatasetError(f"{p}: image name {name!r} appears on lines {first_line[name]} and {line}; each image "
                               "must have one position (hint: remove the duplicate row)")
        first_line[name] = line
    check_names(names, f"{p} (column {header[col['name']]!r})")
    unit = kind
    pos_cols = [col[c] for c in KIND_COLUMNS[unit]]
    pos = _positions(p, header, rows, pos_cols, unit)
    if unit == "degrees":
        check_latlon(pos, str(p), names.lines)
    if unit == "frames":
        check_frames(pos[:, 0], str(p), names.lines, header[pos_cols[0]])
    keys = [r[col["seq"]].strip() for _, r in rows] if "seq" in col else None
    return PositionsTable(names, pos, unit, keys, f"{p} (column {header[col['seq']]!r})" if "seq" in col else None)


NO_FIX = ("", "nan", "na", "n/a", "null", "none", "-")  # a GPS logger's empty position (lat/lon 0, 0 too)


def _positions(p: Path, header: list[str], rows: list[tuple[int, list[str]]], pos_cols: list[int],
               unit: str) -> np.ndarray:
    """``[N, P]`` positions of ``rows``; a value that is no finite number is an error naming its line, rows
    without a fix (every position empty or NaN; lat/lon 0, 0) one error that names them all."""
    pos = np.empty((len(rows), len(pos_cols)), dtype=np.float64)
    no_fix = []
    for i, (line, r) in enumerate(rows):
        try:
            pos[i] = [float(r[c]) for c in pos_cols]
        except ValueError:
            pos[i] = np.nan
        if all(r[c].strip().lower() in NO_FIX for c in pos_cols) or (unit == "degrees" and not pos[i].any()):
            no_fix.append(line)
        elif not (np.abs(pos[i]) <= POSITION_MAX).all():  # NaN too
            comma = any("," in r[c] for c in pos_cols)  # a ';'-separated spreadsheet export with decimal commas
            raise DatasetError(f"{p}, line {line}: position columns {[header[c] for c in pos_cols]} must be finite "
                               f"numbers within ±{POSITION_MAX:g}, got {[r[c][:40] for c in pos_cols]}"
                               + ("; hint: write decimal points, not decimal commas" if comma else "")
                               + ("; hint: frame numbers count frames (0, 1, 2, ...): timestamps?"
                                  if unit == "frames" and not comma else ""))
    if no_fix:
        shown = ", ".join(map(str, no_fix[:5])) + (", ..." if len(no_fix) > 5 else "")
        raise DatasetError(f"{p}: {counted(len(no_fix), 'row')} without a position (empty, NaN"
                           + (" or lat/lon 0, 0" if unit == "degrees" else "") + f": no GPS fix?) on line"
                           f"{'s' if len(no_fix) > 1 else ''} {shown}; hint: give them positions (interpolated "
                           "between the rows around them), or remove those rows and their images (frame-aligned "
                           "or --positives data: the same frames of the other traverse too)")
    return pos


def read_positions_csv(path: str | Path) -> tuple[list[str], np.ndarray, str, np.ndarray | None]:
    """Read a positions CSV: ``(names, positions [N, P], unit, seq_bounds [N, 2] or None)``, rows in the file's
    order (:func:`read_positions_table`; ``names`` is a :class:`CsvNames` that knows each name's line; the
    bounds: :func:`sequence_bounds` of the sequence column)."""
    t = read_positions_table(path)
    bounds = None if t.keys is None else sequence_bounds(t.keys, str(t.column))
    return t.names, t.positions, t.unit, bounds


def _find_columns(header: list[str], p: Path) -> dict[str, int]:
    def first(options: tuple[str, ...]) -> int | None:
        return next((header.index(o) for o in options if o in header), None)

    col = {k: i for k, i in (("name", first(NAME_COLUMNS)), ("east", first(EAST_COLUMNS)),
                             ("north", first(NORTH_COLUMNS)), ("frame", first(FRAME_COLUMNS)),
                             ("lat", first(LAT_COLUMNS)), ("lon", first(LON_COLUMNS)),
                             ("seq", first(SEQUENCE_COLUMNS))) if i is not None}
    if "name" not in col:
        spaced = len(header) == 1 and len(header[0].split()) > 1
        raise DatasetError(f"{p}: header {header} has no image-name column; valid: {', '.join(NAME_COLUMNS)}"
                           + ("; fields are separated by ',', ';' or a tab, not spaces" if spaced else ""))
    pairs = [("east" in col, "north" in col), ("lat" in col, "lon" in col)]
    if any(a != b for a, b in pairs) or not (any(a for a, _ in pairs) or "frame" in col):
        raise DatasetError(f"{p}: header {header} needs easting and northing columns ({'/'.join(EAST_COLUMNS)}, "
                           f"{'/'.join(NORTH_COLUMNS)}), lat and lon columns ({'/'.join(LAT_COLUMNS)}, "
                           f"{'/'.join(LON_COLUMNS)}; degrees) or a frame column ({'/'.join(FRAME_COLUMNS)})")
    return col


def runs_to_bounds(keys: list[str]) -> np.ndarray:
    """``[N, 2]`` half-open range of the run of equal consecutive keys each row belongs to."""
    n = len(keys)
    starts = [0] + [i for i in range(1, n) if keys[i] != keys[i - 1]]
    ends = starts[1:] + [n]
    out = np.empty((n, 2), dtype=np.int64)
    for a, b in zip(starts, ends, strict=True):
        out[a:b] = (a, b)
    return out


def sequence_bounds(keys: list[str], where: str) -> np.ndarray:
    """:func:`runs_to_bounds` of a sequence column's ``keys`` (in route order), with a warning naming the
    column ``where`` when a key occurs in more than one run of rows (rows of sequences interleaved, or a
    column that is no sequence id, such as a camera id: each run becomes its own sequence) and when every
    sequence is shorter than :data:`SHORT_SEQUENCE` frames (sequence methods then have no full window at the
    default sequence length)."""
    bounds = runs_to_bounds(keys)
    starts = np.unique(bounds[:, 0])
    lengths = bounds[starts, 1] - starts
    runs: dict[str, int] = {}
    for s in starts:
        runs[keys[s]] = runs.get(keys[s], 0) + 1
    split = [k for k, c in runs.items() if c > 1]
    if split:
        logger.warning("%s: sequence id %r occurs in %d separate runs of rows (%s); each run of consecutive rows "
                       "is one sequence, so the %s form %s (median length %g); hint: sort the rows so that each "
                       "sequence's rows are together, or drop the column if it is not a sequence id (a camera id?)",
                       where, split[0], runs[split[0]], f"{counted(len(split), 'id')} of {len(runs)} do so",
                       counted(len(keys), "row"), counted(len(starts), "sequence"), float(np.median(lengths)))
    if len(keys) >= SHORT_SEQUENCE and lengths.max() < SHORT_SEQUENCE:
        logger.warning("%s: every sequence is shorter than %d frames (the longest has %d), the default sequence "
                       "length L; sequence methods need --seq-len at most %d, or longer sequences", where,
                       SHORT_SEQUENCE, int(lengths.max()), int(lengths.max()))
    return bounds


def read_seq_bounds(path: str | Path, n: int | None = None) -> np.ndarray:
    """Sequence bounds file (one ``start end`` row per image, half-open) as ``[N, 2]`` int64."""
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"sequence bounds file not found: {p}")
    rows = [ln for ln in read_text(p, "sequence bounds file").splitlines() if ln.split("#")[0].strip()]
    if not rows:  # (loadtxt would warn, then return nothing)
        raise DatasetError(f"{p}: holds no sequence bounds (the file is empty)")
    try:
        b = np.loadtxt(rows, dtype=np.int64, ndmin=2)
    except (ValueError, OverflowError) as e:
        raise DatasetError(f"{p}: expected one 'start end' row of integers per image ({str(e)[:160]})") from e
    if b.shape[1] != 2:
        raise DatasetError(f"{p}: expected 2 columns (start end), got {b.shape[1]}")
    if n is not None and len(b) != n:
        raise DatasetError(f"{p}: {len(b)} sequence-bound rows for {n} images (must be one row per image)")
    return b


EPOCH_LIKE = 1e6  # fractional frame numbers this large are clock times, not places along a route


def check_frames(frames: np.ndarray, where: str, lines: list[int], column: str) -> None:
    """Refuse a frame column ``frames [N]`` of large non-whole numbers (clock timestamps read as frames made
    ``--radius 1`` cover many frames), naming the first such line; warn when the numbers step by other than 1 from
    row to row (``--radius`` counts frame numbers, so it covers another count of rows than it says). Small fractions
    are places along a route (a reference at two frames per query frame: 0, 0.5, 1, ...)."""
    frac = np.flatnonzero(frames != np.round(frames))
    if frac.size and np.abs(frames).max() >= EPOCH_LIKE:
        i = int(frac[0])
        raise DatasetError(f"{where}, line {lines[i]}: frame number {frames[i]:.12g} in column {column!r} is not a "
                           f"whole number ({frac.size} of {len(frames)} rows): timestamps? a frame column counts "
                           "frames; hint: number the frames 0, 1, 2, ... or give positions (easting,northing or "
                           "lat,lon)")
    if len(frames) > 2:
        step = float(np.median(np.abs(np.diff(frames))))
        if step > 0 and not 0.9 <= step <= 1.1:
            logger.warning("%s: the frame numbers in column %r step by %g from one row to the next%s: --radius counts "
                           "frame numbers, so a radius of R covers about %g R rows (hint: number the rows' frames 0, "
                           "1, 2, ... or scale --radius)", where, column, step, " (timestamps?)" if frac.size else "",
                           1 / step)
