"""Describing an image folder into a file, resumably; :func:`main` is the describe stage.

Output files: ``.h5``/``.hdf5`` (datasets ``descriptors`` [N, D] float32 and ``names``, attribute
``config``: the resolved :class:`DescribeConfig`) or ``.npy`` with the names in a text file beside it
(``names.txt`` for ``descriptors.npy``, else ``<stem>.names.txt``) — the formats
:func:`seqnet.data.io.load_descriptors` reads. Work in progress lives in a hidden
``.<out>.partial.h5`` with a per-image status mask (0 to do, 1 done, 2 skipped), so a re-run with the
same settings resumes; a re-run with other settings starts again (with a warning), and a run that
fails before describing any image removes its partial file. Fitted state is kept beside the output
(see :mod:`seqnet.describe.state`).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from ..core.errors import ConfigError, DatasetError, ImageError, OutputError
from ..core.log import logger
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.memory import HDF5_OVERHEAD, check_space
from ..core.provenance import make as make_provenance
from ..core.provenance import sidecar as provenance_sidecar
from ..data.readers import read_descriptor_file
from ..security.dirs import remove_dead_temps
from ..security.files import temp_prefix
from ..security.hdf5file import check_hdf5
from ..security.locks import locked
from .config import DescribeConfig, fit_summary
from .describer import Describer, Sink, describe_images, fit_paths_of, make_describer, run_batches
from .images import ImageList, list_images
from .output import OUT_SUFFIXES, check_sidecars, names_file_for, write_output
from .shards import SHARD_KEY, Shard
from .state import StateFile, provenance_fit, reused_fit, state_files

__all__ = ["OUT_SUFFIXES", "describe_folder", "describe_to_file", "main", "names_file_for"]

TODO, DONE, SKIPPED = 0, 1, 2
BLOCK_BYTES = MEMORY_BLOCK // 2  # descriptors copied per block from the partial file into the output


def partial_file_for(out: str | os.PathLike[str]) -> Path:
    """The hidden work-in-progress file of an output (its name carries seqnet's mark)."""
    out = Path(out)
    return out.with_name(f"{temp_prefix(out.name)}partial.h5")


def main(conf: DescribeConfig, images: str | os.PathLike[str], out: str | os.PathLike[str],
         overwrite: bool = False, shard: Shard | None = None, topic: str | None = None,
         fps: float | None = None) -> Path:
    """The describe stage: describe the folder or list file ``images`` (or the image ``topic`` of the ROS bag
    ``images``) into ``out`` (.h5/.hdf5/.npy).

    Resumes an interrupted run with the same settings; ``overwrite`` recomputes an existing output.
    ``shard``: describe only that slice of the images (:mod:`seqnet.describe.shards`; merge the
    outputs with :func:`seqnet.describe.merge.merge_shards`). Returns the path of the output file.
    """
    describe_folder(images, conf, out=out, overwrite=overwrite, shard=shard, topic=topic, fps=fps)
    return Path(out)


def describe_folder(source: str | os.PathLike[str], conf: DescribeConfig, out: str | os.PathLike[str] | None = None,
                    overwrite: bool = False, shard: Shard | None = None,
                    topic: str | None = None, fps: float | None = None) -> tuple[np.ndarray, list[str]]:
    """Descriptors ``[N, D]`` and names of a folder or list file of images, of the image ``topic`` of a ROS
    bag, or of a video's frames (``fps`` per second; ``shard``: of its slice only); with ``out``, also written there
    resumably (see the module docstring). Logs one summary line."""
    images = list_images(source, topic, fps=fps)
    t0 = time.perf_counter()
    if out is None:
        if shard is not None:
            raise ConfigError(f"shard {shard.index}/{shard.count} needs an output file (out=...) to be merged later")
        desc, names = describe_images(images.paths, conf, names=images.names)
    else:
        desc, names = describe_to_file(images, conf, Path(out), overwrite, shard)
    seconds = time.perf_counter() - t0
    a, b = (0, len(images)) if shard is None else shard.frames(len(images), conf.batch_size)
    logger.info("described %d images of %s%s in %.1f s (%.1f images/s): %d descriptors of dim %d (%s)%s%s", b - a,
                source, f" (shard {shard.index}/{shard.count}: images {a}..{b - 1})" if shard else "", seconds,
                (b - a) / max(seconds, 1e-9), len(desc), desc.shape[1], conf.label,
                f", {b - a - len(desc)} skipped" if len(desc) < b - a else "",
                f", written to {out}" if out is not None else "")
    return desc, names


def describe_to_file(images: ImageList, conf: DescribeConfig, out: Path, overwrite: bool = False,
                     shard: Shard | None = None) -> tuple[np.ndarray, list[str]]:
    """Describe ``images`` (``shard``: its slice of them) into ``out``, resuming a partial run with the same
    settings; the output is locked while it is written (a second describe into it is refused, exit 1, never
    mixed). A shard output records its shard in its provenance (``shard``), which is otherwise the whole run's."""
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise ConfigError(f"output file {out} must end in one of {', '.join(OUT_SUFFIXES)}")
    with locked(out):
        remove_dead_temps([out, names_file_for(out), provenance_sidecar(out)])
        return _describe_to_file(images, conf, out, overwrite, shard)


def _describe_to_file(images: ImageList, conf: DescribeConfig, out: Path, overwrite: bool,
                      shard: Shard | None) -> tuple[np.ndarray, list[str]]:
    if out.exists() and not overwrite:
        raise ConfigError(f"output {out} already exists (hint: --overwrite recomputes it)")
    check_sidecars(out, overwrite)
    conf = conf.resolved()
    partial = partial_file_for(out)
    part = shard.record(len(images), conf.batch_size, images.names) if shard is not None else None
    todo = images if part is None else ImageList(images.paths[slice(*part["frames"])],
                                                 images.names[slice(*part["frames"])])
    settings = json.dumps({**conf.settings(), **({SHARD_KEY: part} if part else {})}, sort_keys=True)
    states = state_files(conf, out, fit_paths_of(conf, images.paths) if conf.needs_fit else [])
    if overwrite:
        _remove_own_state(states)
    if partial.is_symlink() or (partial.exists() and not partial.is_file()):
        raise OutputError(f"{partial} (the partial output of {out}) is a link or not a file; seqnet neither follows "
                          "nor deletes it: remove it")
    if partial.exists() and not _resumable(partial, settings, todo.names, states, overwrite):
        partial.unlink()
    out.parent.mkdir(parents=True, exist_ok=True)
    if not partial.exists():  # libhdf5 must never meet a full disk or a file size limit: it may not fail cleanly
        names_bytes = sum(len(n.encode()) + 24 for n in todo.names)
        check_space(out.parent, HDF5_OVERHEAD + names_bytes, "the partial output's names and status",
                    largest=HDF5_OVERHEAD + names_bytes)
    describer = make_describer(conf, images.paths, sidecar=out)  # fitted on the whole list's images, as unsharded
    try:
        with h5py.File(partial, "a") as h:
            keep = _describe_into(h, todo, describer, settings)
    except BaseException:
        _drop_if_unstarted(partial)
        raise
    if not len(keep):
        partial.unlink()  # nothing worth resuming: a re-run reads every image again
        raise ImageError(f"none of the {len(todo)} images could be read (first: {todo.paths[0]})")
    names = [todo.names[i] for i in keep]
    record = {**conf.to_dict(), "fit": fit_summary(conf.fit)}  # a list of fitting images as its hash
    fitted_on = fit_paths_of(conf, images.paths) if conf.needs_fit else None
    with h5py.File(partial, "r") as h:
        ds = h["descriptors"]
        prov = {**describe_provenance(conf, fitted_on, ds, describer.seen_size), **({SHARD_KEY: part} if part else {})}
        write_output(out, (len(keep), ds.shape[1]), kept_blocks(ds, keep), names, json.dumps(record, sort_keys=True),
                     prov)
    partial.unlink()
    return read_descriptor_file(out)[0], names  # a .npy output memory-mapped


def describe_provenance(conf: DescribeConfig, fitted_on: list[Path] | None, desc: np.ndarray | h5py.Dataset,
                        image_size: tuple[int, int] | None = None) -> dict:
    """The provenance record (:mod:`seqnet.core.provenance`) of descriptors ``desc [N, D]`` (only their
    dimension is read) made with ``conf``, whose fitted state (if any) was fitted on the images ``fitted_on``, from
    images of ``image_size`` ``(W, H)`` as described (:attr:`Describer.seen_size`; recorded beside the id)."""
    settings = {k: v for k, v in conf.settings().items() if k not in ("fit", "fit_max")}
    fit = provenance_fit(fitted_on) if fitted_on is not None else reused_fit(conf, settings)
    if fitted_on is None and fit is not None:  # seqnet's own fitted state, reused as documented: the fitting
        settings["checkpoint"] = None  # run's provenance
    return make_provenance("describe", settings, dim=int(desc.shape[1]), fit=fit, image_size=image_size)


def _describe_into(h: h5py.File, images: ImageList, describer: Describer, settings: str) -> np.ndarray:
    """Run the images still to do into the open partial file; the indices of the images done ``[K]``
    (their descriptors are the rows ``keep`` of ``h["descriptors"]``, left in the file)."""
    if "status" not in h:
        h.attrs["settings"] = settings
        h.create_dataset("names", data=np.array(images.names, dtype=object), dtype=h5py.string_dtype())
        h.create_dataset("status", data=np.full(len(images), TODO, np.int8))
    status = h["status"][()]
    if (status != TODO).any():
        logger.info("resuming: %d of %d images already done", int((status != TODO).sum()), len(status))
    run_batches(images.paths, describer, status == TODO, _h5_sink(h, len(images)))
    return np.flatnonzero(h["status"][()] == DONE)


def kept_blocks(ds: h5py.Dataset, keep: np.ndarray) -> Iterator[np.ndarray]:
    """The rows ``keep`` (increasing) of ``ds [N, D]``, read in consecutive blocks of at most
    :data:`BLOCK_BYTES` (``[<= rows, D]``): the whole array is never held."""
    step = max(1, BLOCK_BYTES // max(1, ds.shape[1] * ds.dtype.itemsize))
    for a in range(0, len(keep), step):
        idx = keep[a : a + step]
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        yield ds[lo:hi] if hi - lo == len(idx) else ds[idx]  # a run of rows is one slice


def _remove_own_state(states: list[StateFile]) -> None:
    """With ``overwrite``: remove the fitted state earlier runs wrote for this output (never another file)."""
    for f in states:
        if f.owned():
            logger.info("--overwrite: removing %s (fitted for this output by an earlier run)", f.path)
            f.path.unlink()


def _resumable(partial: Path, settings: str, names: list[str], states: list[StateFile], overwrite: bool) -> bool:
    """Whether the partial file can be resumed; logs why not."""
    if overwrite:
        logger.info("--overwrite: discarding the partial output %s", partial)
        return False
    try:
        check_hdf5(partial, "partial output")  # read through in the sandbox before this process opens it
        with h5py.File(partial, "r") as h:
            stored = [n.decode() if isinstance(n, bytes) else n for n in h["names"][()]]
            old, done = h.attrs.get("settings"), int((h["status"][()] != TODO).sum())
    except (OSError, KeyError, TypeError, ValueError, DatasetError) as e:
        logger.warning("partial output %s is unreadable (%s); starting again", partial, e)
        return False
    if old != settings or stored != names:
        what = _difference(old, settings) if stored == names else "another image list"
        logger.warning("partial output %s was made with %s; discarding its %d finished images and starting again",
                       partial, what, done)
        return False
    stale = [f.path for f in states if not f.reusable()]
    if stale:
        logger.warning("fitted state %s is missing or from another run; starting %s again", stale[0], partial)
    return not stale


def _difference(old: object, new: str) -> str:
    """``other settings (key: old -> new, ...)`` for a log line."""
    try:
        a, b = json.loads(str(old)), json.loads(new)
    except ValueError:
        return "other settings"
    diff = [f"{k}: {a.get(k)} -> {b.get(k)}" for k in sorted({*a, *b}) if a.get(k) != b.get(k)]
    return f"other settings ({', '.join(diff)})"


def _drop_if_unstarted(partial: Path) -> None:
    """Remove the partial file of a failed run that finished no image (nothing worth resuming)."""
    try:
        with h5py.File(partial, "r") as h:
            started = bool((h["status"][()] != TODO).any())
    except (OSError, KeyError, TypeError, ValueError):
        started = False
    if not started:
        partial.unlink(missing_ok=True)


def _h5_sink(h: h5py.File, n: int) -> Sink:
    def sink(idx: np.ndarray, desc: np.ndarray | None) -> None:
        if desc is not None:
            if "descriptors" not in h:
                size = HDF5_OVERHEAD + n * (desc.shape[1] * 4 + 64)  # the partial file, then the output beside it
                check_space(Path(h.filename).parent, 2 * size, f"{n} descriptors of D={desc.shape[1]}", largest=size)
                h.create_dataset("descriptors", shape=(n, desc.shape[1]), dtype=np.float32,
                                 chunks=(min(n, 256), desc.shape[1]))
            h["descriptors"][np.sort(idx)] = desc[np.argsort(idx)]
        h["status"][np.sort(idx)] = DONE if desc is not None else SKIPPED
        h.flush()

    return sink
