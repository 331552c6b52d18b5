"""Positions from a drive's GPS / INS log, images matched to it by timestamp.

One table, :data:`POSITION_LOGS`, of the logs seqnet reads (``--positions-format``):

* ``robotcar-ins``: Oxford RobotCar ``gps/ins.csv`` (robotcar-dataset-sdk: ``timestamp, ins_status,
  latitude, longitude, altitude, northing, easting, down, utm_zone, velocity_north, ...``; ``gps.csv``
  too: ``timestamp, num_satellites, latitude, longitude, altitude, latitude_sigma, longitude_sigma,
  altitude_sigma, northing, easting, down, utm_zone``), timestamps in microseconds; its ``easting,
  northing`` (UTM metres, in its ``utm_zone``) are used, else ``latitude, longitude``. An image's time
  is its file name (``<timestamp>.png``).
* ``kitti-oxts``: a KITTI raw drive's ``oxts/`` folder: ``data/0000000000.txt`` (one line of 30
  numbers: lat, lon, alt, roll, pitch, yaw, ...) and ``timestamps.txt`` (one
  ``YYYY-MM-DD HH:MM:SS.fffffffff`` line per file): lat / lon. An image's time is its line in
  ``image_0x/timestamps.txt`` (the image ``image_0x/data/<frame>.png``).

Latitude / longitude are kept as degrees here: the two traverses' become UTM metres together, the query in the
reference's zone (:func:`seqnet.data.utm.latlon_pair`, as for a positions CSV), so two drives on either side of a
zone boundary compare. Logged easting / northing stay in the log's zone: two logs in two zones are refused
(:func:`check_zones`, with the way out: :data:`ZONE_HINT`).

Every image takes the position of the nearest log sample; an image farther than the tolerance
(``max_gap`` seconds) from every sample is refused by name, never given a far position.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from ..security.inputs import inside
from ..security.limits import INDEX_MAX
from ..security.text import shown
from .convert import names_flag, read_csv_rows
from .readers import read_descriptor_file, read_provenance, read_text
from .timematch import gap_hint, nearest_within
from .traverse import Traverse
from .utm import check_latlon

DEFAULT_MAX_GAP = 0.1  # seconds: RobotCar's INS logs at 50 Hz, KITTI's oxts at 10 Hz (synced) or 100 Hz
DIGITS = re.compile(r"[0-9]{1,18}")  # a timestamp or frame number: ASCII digits, within int64 ("²".isdigit())
UTM_ZONE = re.compile(r"[0-9]{1,2}[C-HJ-NP-Xc-hj-np-x]?")  # "30U": zone number and latitude band
ZONE_HINT = ("hint: a log without easting, northing columns is read by its latitude, longitude, placed in the "
             "reference's zone: rename those two columns in the logs' headers (e.g. to easting_utm, northing_utm)")


@dataclasses.dataclass(frozen=True)
class Samples:
    """A position log: ``times [S]`` (seconds, sorted), ``positions [S, 2]`` in ``unit``: ``metres`` (easting,
    northing in UTM ``zone``, ``"?"`` when the log names none) or ``degrees`` (latitude, longitude; zone ``"?"``)."""

    times: np.ndarray
    positions: np.ndarray
    zone: str
    unit: str = "metres"


def _times_of(fields: list[str], what: str) -> float:
    text = fields[0].strip()
    if not DIGITS.fullmatch(text) or int(text) > INDEX_MAX:
        raise DatasetError(f"{what}: timestamp {_short(text)} is not an integer (microseconds, at most 18 digits)")
    return int(text) / 1e6


def _short(text: str) -> str:
    """``repr(text)``, cut to 60 characters (a name or value read from a file, shown in a message)."""
    return repr(text) if len(text) <= 60 else repr(text[:57]) + "..."


def _zone(header: list[str], rows: list[tuple[int, list[str]]], p: Path) -> str:
    """The one UTM zone of a RobotCar log's ``utm_zone`` column (``"?"`` without one)."""
    if "utm_zone" not in header:
        return "?"
    col, zones = header.index("utm_zone"), {}
    for line, r in rows:
        z = r[col].strip()
        if z not in zones and not UTM_ZONE.fullmatch(z):
            raise DatasetError(f"{p}, line {line}: utm_zone {_short(z)} is not a UTM zone (e.g. 30U)")
        zones.setdefault(z, line)
    if len(zones) > 1:  # its easting jumps by hundreds of km where the zone changes
        raise DatasetError(f"{p}: easting/northing in {len(zones)} UTM zones ({', '.join(sorted(zones))}), which do "
                           f"not compare; {ZONE_HINT}")
    return next(iter(zones), "?")


def read_robotcar_ins(path: str | Path) -> Samples:
    """RobotCar ``ins.csv`` / ``gps.csv``: times (s) and easting/northing (metres) in its one UTM zone, else (no
    easting, northing columns) latitude/longitude (degrees)."""
    p = Path(path)
    header, rows = read_csv_rows(p)
    has_en = "easting" in header and "northing" in header
    wanted = ["timestamp", *(("easting", "northing") if has_en else ("latitude", "longitude"))]
    missing = [c for c in wanted if c not in header]
    if missing:
        raise DatasetError(f"{p}: no column {', '.join(missing)} (header {header}); RobotCar's ins.csv has "
                           "timestamp, ins_status, latitude, longitude, altitude, northing, easting, ...")
    col = [header.index(c) for c in wanted]
    vals = np.empty((len(rows), 3), dtype=np.float64)
    for i, (line, r) in enumerate(rows):
        if len(r) < len(header):
            raise DatasetError(f"{p}, line {line}: {len(r)} fields, but the header has {len(header)}")
        vals[i, 0] = _times_of([r[col[0]]], f"{p}, line {line}")
        try:
            vals[i, 1:] = [float(r[c]) for c in col[1:]]
        except ValueError:
            vals[i, 1] = np.nan
        if not np.isfinite(vals[i, 1:]).all():
            raise DatasetError(f"{p}, line {line}: {'/'.join(wanted[1:])} must be numbers (finite), got "
                               f"{', '.join(_short(r[c]) for c in col[1:])}")
    if has_en:
        return _sorted(vals[:, 0], vals[:, 1:], _zone(header, rows, p))
    check_latlon(vals[:, 1:], str(p), [line for line, _ in rows])
    return _sorted(vals[:, 0], vals[:, 1:], "?", "degrees")


def _sorted(times: np.ndarray, positions: np.ndarray, zone: str, unit: str = "metres") -> Samples:
    order = np.argsort(times, kind="stable")
    return Samples(times=times[order], positions=np.asarray(positions, dtype=np.float64)[order], zone=zone, unit=unit)


def parse_kitti_time(text: str, where: str) -> float:
    """Seconds since the epoch (UTC) of a KITTI timestamp ``2011-09-26 13:02:25.594360375``."""
    stamp, _, frac = text.strip().partition(".")
    try:
        if frac and not DIGITS.fullmatch(frac):
            raise ValueError(frac)
        t = datetime.datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S").replace(tzinfo=datetime.timezone.utc)
        return t.timestamp() + (float(f"0.{frac}") if frac else 0.0)
    except (ValueError, OverflowError) as err:
        raise DatasetError(f"{where}: {_short(text.strip())} is not a KITTI timestamp (YYYY-MM-DD "
                           "HH:MM:SS.fffffffff)") from err


def read_kitti_times(path: Path) -> np.ndarray:
    """``[F]`` seconds of every line of a KITTI ``timestamps.txt`` (line i: frame i)."""
    if not path.exists():
        raise DatasetError(f"KITTI timestamps file not found: {path}")
    lines = [ln for ln in read_text(path, "KITTI timestamps file").split("\n") if ln.strip()]
    return np.array([parse_kitti_time(ln, f"{path}, line {i + 1}") for i, ln in enumerate(lines)])


def _frame(path: Path, n: int, what: str) -> int:
    if not DIGITS.fullmatch(path.stem) or int(path.stem) >= n:
        raise DatasetError(f"{what}: {shown(path.name)[:80]} is not a frame number within the {n} lines of "
                           "timestamps.txt (KITTI names frames 0000000000, 0000000001, ...)")
    return int(path.stem)


def read_kitti_oxts(path: str | Path) -> Samples:
    """A KITTI ``oxts/`` folder (or the drive folder holding it): times and latitude/longitude (degrees)."""
    p = Path(path)
    p = p / "oxts" if (p / "oxts").is_dir() else p
    files = sorted((p / "data").glob("*.txt")) if (p / "data").is_dir() else []
    if not files:
        raise DatasetError(f"{p}: no data/*.txt files (a KITTI oxts folder holds data/0000000000.txt ... and "
                           "timestamps.txt)")
    times = read_kitti_times(p / "timestamps.txt")
    if len(times) != len(files):
        raise DatasetError(f"{p}: {len(times)} lines in timestamps.txt for {len(files)} data/*.txt files "
                           "(one timestamp per oxts file)")
    ll = np.empty((len(files), 2), dtype=np.float64)
    frames = np.array([_frame(f, len(times), str(p)) for f in files], dtype=np.int64)
    if len(np.unique(frames)) != len(frames):
        raise DatasetError(f"{p}: two data/*.txt files name one frame (KITTI names frames 0000000000, ...)")
    for i, f in enumerate(files):
        vals = read_text(f, "KITTI oxts file").split()
        if len(vals) != 30:
            raise DatasetError(f"{f}: {len(vals)} values, a KITTI oxts file has 30 (lat lon alt roll pitch yaw ...)")
        try:
            ll[i] = float(vals[0]), float(vals[1])
        except ValueError as err:
            raise DatasetError(f"{f}: lat/lon {[_short(v) for v in vals[:2]]} are not numbers") from err
    check_latlon(ll, str(p / "data"))
    return _sorted(times[frames], ll, "?", "degrees")


def robotcar_image_times(paths: list[Path], root: Path | None = None) -> np.ndarray:
    """``[N]`` seconds from RobotCar image names (``<timestamp in microseconds>.png``; no file is read)."""
    return np.array([_times_of([p.stem], f"image {shown(p.name)[:80]}") for p in paths], dtype=np.float64)


def kitti_image_times(paths: list[Path], root: Path | None = None) -> np.ndarray:
    """``[N]`` seconds of KITTI images ``image_0x/data/<frame>.png`` from ``image_0x/timestamps.txt``; with
    ``root`` (image names read from a file, relative to it), that file must be inside ``root``."""
    cache: dict[Path, np.ndarray] = {}
    out = np.empty(len(paths), dtype=np.float64)
    for i, p in enumerate(paths):
        stamps = p.parent.parent / "timestamps.txt"
        if root is not None and stamps not in cache:
            stamps = inside(root, os.path.relpath(stamps, root), f"image {_short(str(p))}: its KITTI timestamps")
        if stamps not in cache:
            cache[stamps] = read_kitti_times(stamps)
        out[i] = cache[stamps][_frame(p, len(cache[stamps]), f"image {p}")]
    return out


@dataclasses.dataclass(frozen=True)
class PositionLog:
    """A kind of position log: how to read it, how to time an image, and the folder image names start from."""

    read: Callable[[Path], Samples]
    image_times: Callable[[list[Path], Path | None], np.ndarray]  # (image files, root of names read from a file)
    image_root: Callable[[Path], Path]  # the folder descriptor names are relative to (without image paths)
    help: str
    other: str = "another run's log"  # a message's guess when no image falls within the log
    unit: str | None = None  # the unit of the times image names are read in (timematch.UNITS), if named by time


POSITION_LOGS: dict[str, PositionLog] = {
    "robotcar-ins": PositionLog(read_robotcar_ins, robotcar_image_times, lambda p: p.parent,
                                   "Oxford RobotCar gps/ins.csv (or gps.csv); images named <timestamp us>.png",
                                   "another run's ins.csv", "microseconds"),
    "kitti-oxts": PositionLog(read_kitti_oxts, kitti_image_times,
                                 lambda p: p if (p / "oxts").is_dir() else p.parent,
                                 "a KITTI drive's oxts/ folder; image times from image_0x/timestamps.txt "
                                 "(descriptor names relative to the drive folder: image_02/data/0000000000.png)",
                                 "another drive's oxts folder"),
}
POSITIONS_FORMATS = ("csv", *POSITION_LOGS)  # csv: the positions CSV (seqnet.data.convert)


def nearest_samples(image_times: np.ndarray, log: Samples, names: list[str], max_gap: float,
                    where: str, other: str = "another run's log", unit: str | None = None) -> np.ndarray:
    """``[N]`` index of the log sample nearest in time to each image; an image more than ``max_gap`` seconds
    from every sample is refused by name, with a hint from :func:`gap_hint`."""
    t = log.times
    return nearest_within(t, image_times, max_gap, lambda bad, gap: (
        f"{where}: image {names[bad[0]]!r} is {gap[bad[0]]:.3f} s from the nearest position sample (tolerance "
        f"{max_gap:g} s; the log spans {t[0]:.3f}..{t[-1]:.3f} s; {bad.size} such images); "
        + gap_hint(t, image_times, bad, gap, other, unit)))


def log_positions(fmt: str, source: str | Path, names: list[str], paths: list[Path] | None = None,
                  max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray, str, str]:
    """``([N, 2] positions, unit, UTM zone)`` of the images ``names`` (files ``paths``, else the names under the
    log's image root) from the position log ``source`` of kind ``fmt`` (:data:`POSITION_LOGS`): easting/northing
    (unit ``metres``) or latitude/longitude (``degrees``, zone ``"?"``), as :class:`Samples`."""
    src = POSITION_LOGS[fmt]
    log = src.read(Path(source))
    root = None
    if paths is None:  # names read from a file: what is read for them stays in the log's image root
        root = src.image_root(Path(source))
        paths = [root / n for n in names]
    idx = nearest_samples(src.image_times(paths, root), log, names, max_gap, f"{source} ({fmt})", src.other,
                          src.unit)
    logger.info("%s: %d images placed from %d %s samples (%s)", source, len(names), len(log.times), fmt,
                f"UTM zone {log.zone}" if log.unit == "metres" else "latitude / longitude")
    return log.positions[idx], log.unit, log.zone


def check_zones(ref_zone: str, query_zone: str, hint: str | None = None) -> None:
    """Both traverses' positions are in one UTM zone (``32V``, or a positions frame: ``UTM zone 32V``, a bag's
    ``odometry frame 'odom'``; an unknown zone, ``"?"``, is let through), else refused (with ``hint``, e.g.
    :data:`ZONE_HINT` for position logs): their metres do not compare."""
    ref, query = (z.removeprefix("UTM zone ") for z in (ref_zone, query_zone))
    if ref == query or "?" in (ref, query):
        return
    said = f"UTM zone {ref}, query positions in {query}; positions in two zones"
    if not (UTM_ZONE.fullmatch(ref) and UTM_ZONE.fullmatch(query)):
        said = f"{ref_zone}, query positions in {query_zone}; positions in two frames"
    raise DatasetError(f"reference positions are in {said} are not comparable" + (f"; {hint}" if hint else ""))


def traverse_from_log(fmt: str, source: str | Path, desc_path: str | Path, names_file: str | Path | None,
                      name: str, max_gap: float = DEFAULT_MAX_GAP) -> tuple[Traverse, str, str]:
    """A traverse from a descriptor file (with image names) placed by a position log; also its positions' unit and
    UTM zone (:func:`log_positions`)."""
    desc, names = read_descriptor_file(desc_path, names_file, beside=True)
    if names is None:
        raise DatasetError(f"{desc_path}: no image names to time the images by; give {names_flag(name)} FILE, an "
                           "HDF5 file with 'names', or a .npy with its names file beside it (FILE.names.txt)")
    positions, unit, zone = log_positions(fmt, source, names, None, max_gap)
    return Traverse(descriptors=desc, positions=positions, names=names, name=name,
                    provenance=read_provenance(desc_path)), unit, zone
