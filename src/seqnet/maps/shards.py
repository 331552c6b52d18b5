"""An IVF index built in shards and merged on disk (``seqnet index build --shards N``, docs/scale.md).

One coarse quantizer (and codebook) is trained once on a sample (:func:`train_ivf`); every shard's
inverted lists are then filled independently with global ids (:func:`build_shard`: the unit another
process or machine can run), the shards in parallel threads here (FAISS releases the GIL); FAISS's
``merge_ondisk`` concatenates the lists, shard after shard, into one ``OnDiskInvertedLists`` file
``<index>.ivfdata`` beside the index (:func:`merge_shards`), which is opened memory-mapped and
read-only (:func:`open_merged`). Each list holds its ids in the order one index built in one process
over the same rows holds them, so the merged index answers exactly as that index does (same
distances, same ids, same ties).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..core.memmaps import read_rows
from ..core.memory import check_space
from ..core.tensors import ArrayLike, to_numpy
from ..search.ann import (
    ADD_BYTES,
    AnnConfig,
    load_index,
    make_index,
    sample_rows,
    save_index,
    set_search_params,
    train_index,
    train_size,
)


def ivfdata_file(index_file: str | os.PathLike[str]) -> Path:
    """The on-disk inverted lists beside a merged index: ``index.faiss`` → ``index.ivfdata``."""
    return Path(index_file).with_suffix(".ivfdata")


def split_rows(n: int, count: int) -> list[tuple[int, int]]:
    """``count`` contiguous ``(a, b)`` row ranges covering ``0..n`` (sizes differ by at most one)."""
    if not 1 <= count <= max(n, 1):
        raise ConfigError(f"shards must be in 1..{n} for {n} vectors, got {count}")
    return [(k * n // count, (k + 1) * n // count) for k in range(count)]


def check_ivf(index: Any, spec: str) -> Any:
    """The IVF part of ``index`` (FAISS ``IndexIVF*``, possibly behind a pre-transform); a sharded build
    of anything else is a :class:`ConfigError`."""
    import faiss

    ivf = faiss.try_extract_index_ivf(index)
    if ivf is None:
        raise ConfigError(f"--shards needs an IVF index (ivf-flat, ivf-pq or an IVF factory string such as "
                          f"'IVF1024,Flat'), got {spec!r}; hint: drop --shards or choose an IVF index")
    if isinstance(index, faiss.IndexIVFPQR):
        raise ConfigError(f"index {spec!r} (IVFPQR) cannot be merged on disk; hint: IVF..,PQ.. instead")
    return ivf


def train_ivf(sample: np.ndarray, n: int, conf: AnnConfig) -> Any:
    """The empty IVF index of ``conf`` sized for ``n`` vectors, trained on ``sample [S, D]``
    (:func:`seqnet.search.ann.train_index`, as an index built in one process is)."""
    index = make_index(sample.shape[1], n, conf)
    check_ivf(index, conf.factory(sample.shape[1], n))
    train_index(index, sample, conf, n)
    return index


def train_sample_size(n: int, conf: AnnConfig, d: int) -> int:
    """How many rows :func:`build_sharded_index` trains on: :func:`seqnet.search.ann.train_size`."""
    index = make_index(d, n, conf)
    check_ivf(index, conf.factory(d, n))
    return train_size(index, n)


def build_shard(trained_file: str | os.PathLike[str], x: ArrayLike, first_id: int,
                out: str | os.PathLike[str]) -> Path:
    """One shard: the trained index of ``trained_file`` with the rows ``x [n, D]`` added under the ids
    ``first_id .. first_id + n - 1`` (their rows in the whole map), written to ``out``."""
    index = load_index(trained_file)
    step = max(1, ADD_BYTES // (4 * x.shape[1]))
    for a in range(0, len(x), step):
        part = read_rows(x, a, a + step) if isinstance(x, np.ndarray) else x[a : a + step]
        block = np.ascontiguousarray(to_numpy(part), dtype=np.float32)
        if not np.isfinite(block).all():
            raise ConfigError(f"shard rows {first_id + a}..{first_id + a + len(block) - 1} hold NaN or inf")
        index.add_with_ids(block, np.arange(first_id + a, first_id + a + len(block), dtype=np.int64))
    return save_index(index, out)


@contextlib.contextmanager
def faiss_chatter() -> Iterator[None]:
    """Send what FAISS's C++ code prints on stdout (``merge_ondisk``, ``IO_FLAG_ONDISK_SAME_DIR``) to the
    debug log instead of the command's output (file descriptor 1 is redirected inside the block)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile() as cap:
        os.dup2(cap.fileno(), 1)
        try:
            yield
        finally:
            _flush_c_stdio()
            os.dup2(saved, 1)
            os.close(saved)
            cap.seek(0)
            for line in cap.read().decode("utf-8", "replace").splitlines():
                logger.debug("faiss: %s", line)


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: C's buffered stdout reaches the redirected descriptor before it is restored."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)


def merge_shards(trained_file: str | os.PathLike[str], shard_files: Sequence[Path],
                 index_file: str | os.PathLike[str]) -> Path:
    """``merge_ondisk`` of the shard indexes into the trained index of ``trained_file``: its inverted lists
    go to ``<index>.ivfdata`` (written through a memory map, so the free space is checked first), the index
    to ``index_file`` (atomically). Call on a fresh folder: the map writer's temporary directory."""
    from faiss.contrib.ondisk import merge_ondisk

    index_file = Path(index_file)
    data = ivfdata_file(index_file)
    check_space(index_file.parent, sum(os.path.getsize(f) for f in shard_files), f"the merged lists {data.name}",
                largest=sum(os.path.getsize(f) for f in shard_files))
    trained = load_index(trained_file)
    with faiss_chatter():
        merge_ondisk(trained, [str(f) for f in shard_files], str(data))
    return save_index(trained, index_file)


def open_merged(index_file: str | os.PathLike[str], conf: AnnConfig | None = None) -> Any:
    """A merged index with its inverted lists memory-mapped read-only from ``<index>.ivfdata`` beside it
    (found in the index's own folder, wherever the folder was moved: ``IO_FLAG_ONDISK_SAME_DIR``)."""
    import faiss

    from ..core.errors import CheckpointError

    try:
        with faiss_chatter():
            index = faiss.read_index(str(index_file), faiss.IO_FLAG_ONDISK_SAME_DIR | faiss.IO_FLAG_READ_ONLY)
    except RuntimeError as e:
        raise CheckpointError(f"cannot open the merged FAISS index {index_file} with its lists "
                              f"{ivfdata_file(index_file).name} ({str(e).splitlines()[0][:200]})") from e
    if conf is not None:
        set_search_params(index, conf)
    return index


def build_sharded_index(shards: Sequence[ArrayLike], conf: AnnConfig, index_file: str | os.PathLike[str],
                        workers: int | None = None, trained: Any = None) -> Path:
    """The IVF index of ``conf`` over the rows of ``shards`` (``[n_k, D]`` each, e.g. memory maps), one after
    the other, built shard by shard in ``workers`` threads (default: one per shard, at most the CPUs) and
    merged on disk into ``index_file`` + ``<index>.ivfdata``. ``trained``: an already trained empty index
    (default: :func:`train_ivf` on :func:`sample_rows` of all rows, :func:`seqnet.search.ann.train_size` of them)."""
    index_file = Path(index_file)
    n, d = sum(len(x) for x in shards), int(shards[0].shape[1])
    if trained is None:
        trained = train_ivf(sample_rows(_Rows(shards), train_sample_size(n, conf, d)), n, conf)
    check_ivf(trained, conf.kind)
    work = Path(tempfile.mkdtemp(dir=index_file.parent, prefix=f".{index_file.name}.", suffix=".tmp"))
    try:
        trained_file = save_index(trained, work / "trained.faiss")
        firsts = np.cumsum([0, *(len(x) for x in shards)])[:-1]
        files = [work / f"shard-{k}.faiss" for k in range(len(shards))]
        with ThreadPoolExecutor(max_workers=workers or min(len(shards), os.cpu_count() or 1)) as pool:
            list(pool.map(lambda k: build_shard(trained_file, shards[k], int(firsts[k]), files[k]),
                          range(len(shards))))
        logger.info("built %d shard indexes (%d vectors of D=%d); merging them on disk", len(shards), n, d)
        merge_shards(trained_file, files, index_file)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return index_file


class _Rows:
    """Row indexing ``rows[idx]`` across consecutive arrays (for sampling the training rows)."""

    def __init__(self, parts: Sequence[ArrayLike]) -> None:
        self.parts, self.starts = parts, np.cumsum([0, *(len(p) for p in parts)])

    def __len__(self) -> int:
        return int(self.starts[-1])

    def __getitem__(self, idx: np.ndarray) -> np.ndarray:
        k = np.searchsorted(self.starts, idx, side="right") - 1
        return np.concatenate([to_numpy(self.parts[j][idx[k == j] - self.starts[j]]) for j in np.unique(k)])
