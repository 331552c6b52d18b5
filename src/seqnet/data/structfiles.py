"""Read the original SeqNet / NetVLAD ground-truth files (``.db``) and convert them to datasets.

A ``.db`` file is a MATLAB v5 ``.mat`` file with a top-level struct ``dbStruct``: whichSet,
dbImageFns [N], qImageFns [M], numImages, numQueries, posDistThr, posDistSqThr,
nonTrivPosDistSqThr, utmDb / utmQ (``[2, N]`` UTM metres — in the order the file stores them — or
``[1, N]`` frame indices for Nordland) and, for Nordland, gpsDb / gpsQ. For training sets,
``posDistThr`` is the negative radius and ``sqrt(nonTrivPosDistSqThr)`` the positive radius.

Descriptors come from the published ``.npy`` files: either one row per struct image, or (for
frame-indexed structs such as Nordland) the descriptors of the whole frame list, indexed by the
struct's frame numbers. MSLS sequence-bound files (one ``start end`` row per image) are optional.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from ..security.limits import INDEX_MAX, number
from ..security.matlab import read_struct
from ..security.text import shown
from .convert import POSITION_MAX, read_seq_bounds
from .presets import get_preset, preset_metadata, preset_splits
from .readers import LINE_SEPARATORS
from .traverse import Dataset, Traverse

REQUIRED_FIELDS = ("whichSet", "dbImageFns", "qImageFns", "numImages", "numQueries", "posDistThr", "utmDb", "utmQ")


@dataclasses.dataclass
class DbStruct:
    """The content of one SeqNet ``.db`` file (positions as ``[N, P]`` rows, P = 1 or 2)."""

    path: Path
    which_set: str
    dataset: str
    db_names: list[str]
    q_names: list[str]
    utm_db: np.ndarray  # [N, P]
    utm_q: np.ndarray  # [M, P]
    pos_dist_thr: float
    pos_dist_sq_thr: float
    non_triv_pos_dist_sq_thr: float | None

    @property
    def frames(self) -> bool:
        """Whether positions are 1-D frame indices (Nordland) rather than UTM metres."""
        return self.utm_db.shape[1] == 1


def _scalar(s: dict[str, np.ndarray], field: str, path: Path, hi: float = POSITION_MAX,
            integer: bool = False) -> float:
    """A number field of the struct, in ``0..hi`` (a threshold: above 0)."""
    a = np.asarray(s[field])
    if a.size != 1 or a.dtype.kind not in "biuf":
        raise DatasetError(f"{path}: dbStruct.{field} must be one number, got {a.dtype} of shape {a.shape}")
    return number(a.ravel()[0].item(), f"{path}: dbStruct.{field}", 0 if integer else 1e-9, hi, integer=integer)


def _text(v: object, where: str) -> str:
    """A MATLAB string (a char array, or a cell holding one) as str; else :class:`DatasetError`."""
    a = np.asarray(v)
    while a.dtype == object and a.size == 1:
        a = np.asarray(a.ravel()[0])
    if a.dtype.kind != "U" or a.size != 1 or not str(a.ravel()[0]):
        got = "a struct or another MATLAB type" if a.dtype.names else f"{a.dtype} of shape {a.shape}"
        raise DatasetError(f"{where} must be a non-empty string, got {got}")
    text = str(a.ravel()[0])
    if "\x00" in text or not LINE_SEPARATORS.isdisjoint(text):
        raise DatasetError(f"{where} {text[:80]!r} contains a NUL or a line break")
    return text


def _names(v: np.ndarray, field: str, path: Path) -> list[str]:
    flat = np.asarray(v, dtype=object).ravel()
    return [_text(x, f"{path}: dbStruct.{field}[{i}]") for i, x in enumerate(flat)]


def _utm(v: np.ndarray, n: int, field: str, path: Path) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise DatasetError(f"{path}: dbStruct.{field} must hold numbers (UTM or frame indices), got "
                           f"{np.asarray(v).dtype}") from err
    if a.ndim != 2 or a.shape[0] not in (1, 2) or a.shape[1] != n:
        raise DatasetError(f"{path}: dbStruct.{field} must be [2, {n}] (UTM) or [1, {n}] (frames), "
                           f"got shape {a.shape}")
    if not (np.abs(a) <= POSITION_MAX).all():
        raise DatasetError(f"{path}: dbStruct.{field} holds NaN, inf or values beyond ±{POSITION_MAX:g}")
    return a.T.copy()


def read_db_struct(path: str | Path) -> DbStruct:
    """Parse a SeqNet ``.db`` file (checked, then read in a child: :mod:`seqnet.security.matlab`);
    :class:`DatasetError` names a missing or malformed field."""
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"struct file not found: {p}")
    variables, s = read_struct(p, "dbStruct")
    if "dbStruct" not in variables:
        raise DatasetError(f"{p}: no top-level 'dbStruct' (found: {', '.join(shown(v) for v in variables[:20])})")
    if s is None:
        raise DatasetError(f"{p}: 'dbStruct' is empty or not a struct (hint: pass a seqNet structFiles/*.db)")
    fields = tuple(s)
    missing = [f for f in REQUIRED_FIELDS if f not in fields]
    if missing:
        raise DatasetError(f"{p}: dbStruct lacks field(s) {', '.join(missing)} (has: "
                           f"{', '.join(shown(f) for f in fields[:40])})")
    db_names, q_names = _names(s["dbImageFns"], "dbImageFns", p), _names(s["qImageFns"], "qImageFns", p)
    for field, names in (("numImages", db_names), ("numQueries", q_names)):
        if (count := _scalar(s, field, p, INDEX_MAX, integer=True)) != len(names):
            raise DatasetError(f"{p}: dbStruct.{field} = {count} but {len(names)} image names")
        if not names:
            raise DatasetError(f"{p}: dbStruct.{field} = 0: a struct file of no images describes no place")
    thr = _scalar(s, "posDistThr", p)
    return DbStruct(
        path=p,
        which_set=_text(s["whichSet"], f"{p}: dbStruct.whichSet"),
        dataset=_text(s["dataset"], f"{p}: dbStruct.dataset") if "dataset" in fields else p.stem,
        db_names=db_names,
        q_names=q_names,
        utm_db=_utm(s["utmDb"], len(db_names), "utmDb", p),
        utm_q=_utm(s["utmQ"], len(q_names), "utmQ", p),
        pos_dist_thr=thr,
        pos_dist_sq_thr=_scalar(s, "posDistSqThr", p) if "posDistSqThr" in fields else thr**2,
        non_triv_pos_dist_sq_thr=_scalar(s, "nonTrivPosDistSqThr", p) if "nonTrivPosDistSqThr" in fields else None,
    )


def select_descriptors(desc: np.ndarray, positions: np.ndarray, n: int, frames: bool, what: str) -> np.ndarray:
    """The ``[n, D]`` descriptors of a struct's images from a descriptor array ``desc [N, D]``.

    ``desc`` holds either exactly the struct's ``n`` images, or (frame-indexed structs) the whole
    frame list, gathered at the struct's frame indices ``positions [n, 1]``.
    """
    if desc.ndim != 2:
        raise DatasetError(f"{what}: descriptors must be [N, D], got shape {tuple(desc.shape)}")
    if desc.shape[0] == n:
        return desc
    if frames:
        idx = positions[:, 0].astype(np.int64)
        if np.array_equal(idx, positions[:, 0]) and idx.min() >= 0 and idx.max() < desc.shape[0]:
            return np.asarray(desc[idx])
        raise DatasetError(f"{what}: {desc.shape[0]} descriptors, but the struct's frame indices span "
                           f"{int(positions.min())}..{int(positions.max())} (need one row per struct image, "
                           "or the whole frame list)")
    raise DatasetError(f"{what}: {desc.shape[0]} descriptors for {n} struct images; hint: give the descriptors of "
                       "exactly the struct's images, in its order (one file per --db)")


def _radii(structs: list[DbStruct], preset: str | None, radius: float | None) -> dict[str, float]:
    """Localisation radius and training radii: explicit > preset > struct files."""
    test = next((s for s in structs if s.which_set == "test"), structs[-1])
    train = next((s for s in structs if s.which_set == "train"), None)
    out = {"radius": test.pos_dist_thr}
    if train is not None:
        out["neg_radius"] = train.pos_dist_thr
        if train.non_triv_pos_dist_sq_thr is not None:
            out["pos_radius"] = float(np.sqrt(train.non_triv_pos_dist_sq_thr))
    if preset is not None:
        meta = get_preset(preset)
        for key in ("radius", "pos_radius", "neg_radius"):
            if key in out and out[key] != meta[key]:
                logger.warning("preset %s: %s %g overrides the struct files' %g", preset, key, meta[key], out[key])
            out[key] = float(meta[key])
    if radius is not None:
        out["radius"] = float(radius)
    return out


def _side(structs, descs, bounds, get, what) -> Traverse:  # noqa: ANN001 - internal helper
    """Concatenate one side (reference or query) of all structs."""
    parts, pos, names, bnd, off = [], [], [], [], 0
    for i, s in enumerate(structs):
        p, n = get(s)
        d = descs[0] if len(descs) == 1 else descs[i]
        parts.append(select_descriptors(d, p, len(n), s.frames, f"{what} descriptors for {s.path.name}"))
        pos.append(p)
        names += n
        b = read_seq_bounds(bounds[i], len(n)) if bounds else np.tile([[0, len(n)]], (len(n), 1))
        bnd.append(b + off)
        off += len(n)
    desc = parts[0] if len(parts) == 1 else np.concatenate([np.asarray(x) for x in parts])
    seq = np.concatenate(bnd) if (bounds or len(structs) > 1) else None
    return Traverse(descriptors=desc, positions=np.concatenate(pos), names=names, seq_bounds=seq, name=what)


def dataset_from_structs(
    structs: list[DbStruct],
    ref_desc: list[np.ndarray],
    query_desc: list[np.ndarray],
    preset: str | None = None,
    ref_bounds: list[str | Path] | None = None,
    query_bounds: list[str | Path] | None = None,
    radius: float | None = None,
    name: str | None = None,
) -> Dataset:
    """A dataset from one or more struct files (one split per ``whichSet``, in the order given).

    Args:
        structs: parsed ``.db`` files (e.g. train, val and test of one benchmark).
        ref_desc / query_desc: one descriptor array for all structs, or one per struct.
        preset: preset name; its radii override the struct files' (a warning says when they differ).
        ref_bounds / query_bounds: optional sequence-bound files, one per struct.
        radius: explicit localisation radius (overrides preset and struct).
        name: dataset name (default: the struct's ``dataset`` field).
    """
    if not structs:
        raise DatasetError("no struct file given (hint: --db FILE.db, repeatable)")
    for what, lst, ok in (("--ref-desc", ref_desc, (1, len(structs))), ("--query-desc", query_desc, (1, len(structs))),
                          ("--ref-seq-bounds", ref_bounds or [], (0, len(structs))),
                          ("--query-seq-bounds", query_bounds or [], (0, len(structs)))):
        if len(lst) not in ok:
            raise DatasetError(f"{len(lst)} {what} files for {len(structs)} struct files; give one per --db"
                               + (" (or one for all)" if "desc" in what else ""))
    if len({s.frames for s in structs}) > 1:
        raise DatasetError("struct files mix frame-indexed and UTM positions")
    ref = _side(structs, ref_desc, ref_bounds, lambda s: (s.utm_db, s.db_names), "reference")
    qry = _side(structs, query_desc, query_bounds, lambda s: (s.utm_q, s.q_names), "query")
    splits, ro, qo = {}, 0, 0
    for s in structs:
        key = s.which_set if s.which_set not in splits else f"{s.which_set}:{s.path.stem}"
        splits[key] = {"reference": (ro, ro + len(s.db_names)), "query": (qo, qo + len(s.q_names))}
        ro, qo = ro + len(s.db_names), qo + len(s.q_names)
    radii = _radii(structs, preset, radius)
    extra = {"source": {"format": "seqnet-structfiles", "files": [s.path.name for s in structs]}}
    if preset:
        extra.update(preset_metadata(preset))
    extra.update({k: v for k, v in radii.items() if k != "radius"})
    return Dataset(reference=ref, query=qry, radius=radii["radius"],
                   position_unit="frames" if structs[0].frames else "metres", splits=splits,
                   name=name or structs[0].dataset, extra=extra)


def dataset_from_frame_lists(
    ref_desc: np.ndarray, query_desc: np.ndarray, preset: str, names: list[str] | None = None,
    name: str | None = None,
) -> Dataset:
    """A dataset over whole frame lists (e.g. Nordland summer/winter), split by the preset's index ranges.

    Positions are the frame indices ``0..N-1`` (``[N, 1]``); reference and query frame ``i`` are the same place.
    """
    p = get_preset(preset)
    if p["position_unit"] != "frames":
        raise DatasetError(f"preset {preset!r} has positions in {p['position_unit']}; a frame-list dataset needs a "
                           "frame-indexed preset (nordland) — hint: pass --db struct files instead")
    splits = preset_splits(preset, ref_desc.shape[0], query_desc.shape[0])
    def names_for(n: int) -> list[str] | None:
        return names[:n] if names is not None and len(names) >= n else None

    ref = Traverse(descriptors=ref_desc, positions=np.arange(ref_desc.shape[0]), names=names_for(len(ref_desc)),
                   name="reference")
    qry = Traverse(descriptors=query_desc, positions=np.arange(query_desc.shape[0]), names=names_for(len(query_desc)),
                   name="query")
    return Dataset(reference=ref, query=qry, radius=float(p["radius"]), position_unit="frames", splits=splits,
                   name=name or p["name"], extra={**preset_metadata(preset), "source": {"format": "frame-lists"}})
