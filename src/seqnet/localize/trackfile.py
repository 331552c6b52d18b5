"""The track file of ``seqnet localize``: ``track.csv`` (one row per query frame, :data:`TRACK_COLUMNS`) and
its summary ``track.json`` beside it.

Both are written atomically; the summary is bound to the track it summarises (the size and sampled hash of
the CSV, ``track``) and, while a new track is renamed into place, also holds the record of the track it
replaces (``replaces``), so whichever track a kill leaves, the summary of that very track is beside it.
Names read from files are written through :func:`seqnet.security.text.csv_cell` (no spreadsheet formula).
An existing track or summary is replaced only when seqnet localize wrote it.
"""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, DatasetError, OutputError
from ..security.digests import file_digest
from ..security.files import atomic_path, write_json_atomic
from ..security.inputs import open_input
from ..security.jsonfile import read_json
from ..security.text import csv_cell
from .localizer import Estimate

TRACK_COLUMNS = ("frame", "name", "estimate", "estimate_name", "score", "confidence", "latency_ms", "correct",
                 "full_window")
ACCEPTED = "accepted"  # the column a calibrated track adds (--target-precision): 1 accept, 0 abstain
# the columns a track with ground-truth positions adds, last: each frame's true position (x, y: the map's positions,
# metres or frame numbers) and the distance from it to the estimate's reference position (empty: no truth or answer)
TRUTH_COLUMNS = ("true_x", "true_y", "error")
TRACK_KIND = "seqnet-localize/1"
BOUND = "track"  # in the summary: the size and sampled hash of the track it summarises


def sidecar_of(out: Path) -> Path:
    """``track.json`` beside ``track.csv``."""
    return out.with_suffix(".json")


def check_output(out: str | Path) -> Path:
    """``out`` must end in .csv; it and its ``.json`` sidecar may only replace what this stage wrote."""
    out = Path(out)
    if out.suffix.lower() != ".csv":
        raise ConfigError(f"--out {out} must be a .csv file (one row per query frame)")
    side = sidecar_of(out)
    if side.exists() and not _our_summary(side):
        raise OutputError(f"{side} exists and was not written by seqnet localize; the summary of {out.name} "
                          "goes there: move it away or choose another --out")
    if out.exists() and not (side.exists() or _our_header(out)):
        raise OutputError(f"{out} exists and was not written by seqnet localize; move it away or choose another "
                          "--out")
    return out


def _our_summary(side: Path) -> bool:
    try:
        record = read_json(side, "track summary", OutputError, limit=1 << 26)
    except OutputError:
        return False
    return isinstance(record, dict) and record.get("kind") == TRACK_KIND


def _our_header(out: Path) -> bool:
    """A track whose summary was never written (a run killed between the two files) starts with our header."""
    try:
        with open_input(out, "track", OutputError) as f:
            header = f.readline(4096).decode("utf-8").rstrip("\n").split(",")
    except (OSError, UnicodeDecodeError, OutputError):
        return False
    n = len(TRACK_COLUMNS)
    return tuple(header[:n]) == TRACK_COLUMNS and all(c in (ACCEPTED, *TRUTH_COLUMNS) for c in header[n:])


def read_summary(out: Path) -> dict[str, Any] | None:
    """The summary of the track now at ``out`` (the record bound to it: :data:`BOUND` equal to its size and
    sampled hash); None when there is none; :class:`DatasetError` when the summary belongs to another track."""
    side = sidecar_of(Path(out))
    if not side.is_file():
        return None
    record = read_json(side, "track summary", limit=1 << 26)
    digest = file_digest(out) if Path(out).is_file() else None
    for cand in (record, record.get("replaces") if isinstance(record, dict) else None):
        if isinstance(cand, dict) and cand.get(BOUND) == digest:
            return {k: v for k, v in cand.items() if k not in (BOUND, "replaces")}
    raise DatasetError(f"{side} summarises another track than the one now in {out} (a localize run stopped between "
                       "its two files?); hint: run it again")


@dataclasses.dataclass
class FrameTruth:
    """Each query frame's true position ``positions [Nq, P]`` (a NaN row: no truth for that frame) and the distance
    ``error [Nq]`` from it to the reference position of its estimate (NaN: no truth or no answer), in ``unit`` (the
    map's positions: ``metres``, ``frames``; None when unknown)."""

    positions: np.ndarray
    error: np.ndarray
    unit: str | None

    @classmethod
    def of(cls, q_pos: np.ndarray | None, r_pos: np.ndarray, best: np.ndarray,
           unit: str | None) -> FrameTruth | None:
        """The truth of query frames at ``q_pos [Nq, P]`` (None: no ground truth, gives None) whose estimates are
        ``best [Nq]`` (-1: none; rows of the reference positions ``r_pos [Nr, P]``)."""
        if q_pos is None:
            return None
        best = np.asarray(best, np.int64)
        q = np.asarray(q_pos, np.float64).reshape(len(best), -1)
        r = np.asarray(r_pos, np.float64).reshape(len(r_pos), -1)
        err = np.full(len(best), np.nan)
        ok = (best >= 0) & np.isfinite(q).all(axis=1)
        err[ok] = np.linalg.norm(q[ok] - r[best[ok]], axis=1)
        return cls(q, err, unit)

    def cells(self, i: int) -> dict[str, str]:
        """Frame ``i``'s :data:`TRUTH_COLUMNS` (empty cells where unknown)."""
        x = self.positions[i]
        known = bool(np.isfinite(x).all())
        coord = [f"{x[k]:.3f}" if known and k < len(x) else "" for k in (0, 1)]
        err = f"{self.error[i]:.3f}" if np.isfinite(self.error[i]) else ""
        return dict(zip(TRUTH_COLUMNS, (*coord, err), strict=True))

    def record(self) -> dict[str, Any]:
        """The summary's ``truth``: the unit, each frame's true position and error (null where unknown: JSON holds
        no NaN), and the median and mean error over the frames with both."""
        known = np.isfinite(self.error)
        rows = [[round(float(v), 3) for v in x] if np.isfinite(x).all() else None for x in self.positions]
        return {"unit": self.unit, "true_positions": rows,
                "errors": [round(float(e), 3) if np.isfinite(e) else None for e in self.error],
                "frames_with_error": int(known.sum()),
                "error_median": float(np.median(self.error[known])) if known.any() else None,
                "error_mean": float(self.error[known].mean()) if known.any() else None}


def track_rows(est: Sequence[Estimate], q_names: list[str] | None, r_names: list[str] | None,
               correct: np.ndarray | None, accepted: np.ndarray | None = None,
               truth: FrameTruth | None = None, known: np.ndarray | None = None) -> list[dict[str, Any]]:
    """One row per query frame (:data:`TRACK_COLUMNS`); ``correct`` is empty without ground truth or answer (and
    where ``known [Nq]``, the frames whose truth is known, is False: a video's frames outside its track);
    with ``accepted [Nq]`` (a calibrated threshold's decisions) the column :data:`ACCEPTED` too; with ``truth``
    (:func:`frame_truth`) the columns :data:`TRUTH_COLUMNS`, last."""
    rows = []
    for i, e in enumerate(est):
        answered = e.ref_index >= 0
        rows.append({
            "frame": e.frame, "name": csv_cell(q_names[i]) if q_names else "", "estimate": e.ref_frame,
            "estimate_name": csv_cell(r_names[e.ref_frame]) if r_names and answered else "",
            "score": f"{e.score:.6g}" if answered else "", "confidence": f"{e.confidence:.6f}",
            "latency_ms": f"{e.latency_ms:.3f}",
            "correct": int(correct[i]) if correct is not None and answered and (known is None or known[i]) else "",
            "full_window": int(e.full_window)})
        if accepted is not None:
            rows[-1][ACCEPTED] = int(accepted[i])
        if truth is not None:
            rows[-1].update(truth.cells(i))
    return rows


def write_track(out: Path, rows: list[dict[str, Any]], record: dict[str, Any]) -> Path:
    """``out`` (CSV) and its JSON summary ``record`` (with ``kind``), in the order of the module docstring: the
    summary, bound to the new track and holding the replaced track's record, then the track, then the summary
    alone."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else list(TRACK_COLUMNS), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    try:
        previous = read_summary(out) if out.is_file() else None
    except DatasetError:
        previous = None
    old = {"kind": TRACK_KIND, **previous, BOUND: file_digest(out)} if previous is not None else None
    with atomic_path(out) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
        new = {"kind": TRACK_KIND, **record, BOUND: file_digest(tmp)}
        write_json_atomic(sidecar_of(out), {**new, "replaces": old} if old else new)
    if old:
        write_json_atomic(sidecar_of(out), new)
    return out
