"""Approximate nearest-neighbour shortlists with FAISS, built from ``faiss.index_factory`` strings.

The HVPR shortlist only has to contain the true place among its K candidates, so an approximate
index (IVF, HNSW, product quantisation, ...) can replace the exhaustive search on large maps. An
index is named either by an alias of :data:`ANN_INDEXES` (``flat``, ``ivf-flat``, ``hnsw``,
``ivf-pq``: factory strings sized from :class:`AnnConfig` and the number of vectors) or by any
FAISS factory string (``OPQ16,IVF1024,PQ16``, ``HNSW32,SQ8``, ``IVF256,Flat``; see the FAISS wiki
"The index factory"). Every index is L2 over ``[N, D]`` float32 descriptors;
:func:`shortlist_recall` measures how many of the exact top-K it keeps.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import Config, check_int
from ..core.errors import CheckpointError, ConfigError, ResourceError
from ..core.memmaps import read_rows, take_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.tensors import to_numpy

TRAIN_PER_LIST = 256  # training vectors per IVF list (FAISS's own k-means cap)
ADD_BYTES = MEMORY_BLOCK // 2  # vectors added to an index per block
# upper bounds of the settings (a map.json is read from anywhere: ef_search 10**12 must not allocate or hang)
LIMITS = {"nlist": 1 << 24, "nprobe": 1 << 24, "hnsw_m": 1 << 10, "ef_search": 1 << 16, "ef_construction": 1 << 16,
          "pq_m": 1 << 12}
FACTORY = re.compile(r"^[A-Za-z][A-Za-z0-9_,.=x]*$")  # the characters of a faiss factory string


@dataclasses.dataclass(frozen=True)
class AnnConfig(Config):
    """Settings of an approximate index (those of other kinds are ignored).

    Attributes:
        kind: an alias of :data:`ANN_INDEXES` (``flat`` is exact) or a FAISS factory string.
        nlist: IVF aliases: number of inverted lists (None: about ``4·√N``).
        nprobe: IVF: lists visited per query.
        hnsw_m: ``hnsw``: neighbours per node; ef_search / ef_construction: HNSW search / build breadth.
        pq_m: ``ivf-pq``: sub-quantisers (must divide D); pq_bits: bits per sub-quantiser code.
        seed: k-means seed.
    """

    kind: str = "flat"
    nlist: int | None = None
    nprobe: int = 16
    hnsw_m: int = 32
    ef_search: int = 128
    ef_construction: int = 80
    pq_m: int = 16
    pq_bits: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or not (self.kind in ANN_INDEXES or FACTORY.match(self.kind)):
            raise ConfigError(f"ANN index kind {self.kind!r} is neither an alias ({', '.join(ANN_INDEXES)}) nor a "
                              "FAISS factory string such as 'IVF1024,PQ16' or 'HNSW32,SQ8'")
        if self.nlist is not None:
            self._set("nlist", check_int("nlist", self.nlist, 1, LIMITS["nlist"]))
        for key in ("nprobe", "hnsw_m", "ef_search", "ef_construction", "pq_m"):
            self._set(key, check_int(key, getattr(self, key), 1, LIMITS[key]))
        self._set("pq_bits", check_int("pq_bits", self.pq_bits, 1, 16))
        self._set("seed", check_int("seed", self.seed, 0))

    def lists(self, n: int) -> int:
        """IVF lists for ``n`` vectors (at most n / 39, FAISS's minimum training points per list)."""
        return max(1, min(self.nlist or int(4 * np.sqrt(n)), n // 39 or 1))

    def factory(self, d: int, n: int) -> str:
        """The FAISS factory string of this index for ``n`` vectors of dimension ``d``."""
        return ANN_INDEXES[self.kind](d, n, self) if self.kind in ANN_INDEXES else self.kind


def _ivf_pq(d: int, n: int, conf: AnnConfig) -> str:
    if d % conf.pq_m:
        raise ConfigError(f"IVF-PQ needs pq_m dividing D={d}, got pq_m={conf.pq_m} "
                          f"(hint: --pq-m {max(m for m in range(1, min(d, 64) + 1) if d % m == 0)})")
    if n < 2**conf.pq_bits:
        raise ConfigError(f"IVF-PQ with {conf.pq_bits}-bit codes needs at least {2**conf.pq_bits} vectors, got {n}")
    return f"IVF{conf.lists(n)},PQ{conf.pq_m}x{conf.pq_bits}"


# alias -> factory string of (D, N, settings)
ANN_INDEXES: dict[str, Callable[[int, int, AnnConfig], str]] = {
    "flat": lambda d, n, conf: "Flat",
    "ivf-flat": lambda d, n, conf: f"IVF{conf.lists(n)},Flat",
    "hnsw": lambda d, n, conf: f"HNSW{conf.hnsw_m}",
    "ivf-pq": _ivf_pq,
}


def make_index(d: int, n: int, conf: AnnConfig) -> Any:
    """The (untrained, empty) FAISS index of ``conf`` for ``n`` vectors of dimension ``d``; a bad factory
    string is a :class:`ConfigError` naming it (checked before any work)."""
    import faiss

    spec = conf.factory(d, n)
    try:
        index = faiss.index_factory(d, spec, faiss.METRIC_L2)
    except RuntimeError as e:
        raise ConfigError(f"FAISS cannot make index {spec!r} for D={d} ({str(e).strip().splitlines()[-1][:160]}); "
                          f"valid: an alias ({', '.join(ANN_INDEXES)}) or a factory string such as 'IVF1024,PQ16'"
                          ) from e
    hnsw = _hnsw_of(index)
    if hnsw is not None:
        hnsw.efConstruction = conf.ef_construction
    return index


def _inner(index: Any) -> Any:
    """``index`` without its pre-transforms (OPQ, PCA, ...)."""
    import faiss

    while isinstance(index, faiss.IndexPreTransform):
        index = faiss.downcast_index(index.index)
    return index


def _hnsw_of(index: Any) -> Any:
    """The HNSW graph inside ``index`` (through pre-transforms), or None."""
    return getattr(_inner(index), "hnsw", None)


def build_index(ref: np.ndarray, conf: AnnConfig | None = None) -> Any:
    """The FAISS index of ``conf`` over ``ref [N, D]`` (any float array or memory map), trained when the
    index needs training (on :func:`sample_rows`, :func:`train_size` of them) and filled in blocks, so no
    float32 copy of ``ref`` is made beside the index."""
    conf = conf or AnnConfig()
    if ref.ndim != 2 or len(ref) == 0:
        raise ConfigError(f"an index needs a non-empty [N, D] array, got shape {ref.shape}")
    index = make_index(ref.shape[1], len(ref), conf)
    if not index.is_trained:
        train_index(index, sample_rows(ref, train_size(index, len(ref))), conf, len(ref))
    step = max(1, ADD_BYTES // (4 * ref.shape[1]))
    for a in range(0, len(ref), step):
        index.add(np.ascontiguousarray(read_rows(ref, a, a + step), dtype=np.float32))
    set_search_params(index, conf)
    return index


def index_bytes(index: Any, n: int, sample: bool = True) -> int:
    """Estimated bytes of ``index`` (empty, from :func:`make_index`) once it holds ``n`` vectors, with its
    training sample: FAISS's code size per vector (through pre-transforms), 8 bytes of id per vector in
    an inverted list, and an HNSW graph's level-0 links (4 bytes each, 10 % for the upper levels); without
    ``sample``, the codes only (a shard of an index trained once)."""
    return int(n * _code_bytes(_inner(index)) + (train_sample_bytes(index, n) if sample else 0))


def train_sample_bytes(index: Any, n: int) -> int:
    """Bytes of the float32 sample an untrained ``index`` for ``n`` vectors is trained on (0 when trained)."""
    return 0 if index.is_trained else 4 * index.d * train_size(index, n)


def _code_bytes(index: Any) -> float:
    """Bytes per vector of a (downcast) FAISS index without pre-transform."""
    import faiss

    index = faiss.downcast_index(index)
    hnsw = getattr(index, "hnsw", None)
    if hnsw is not None:
        return _code_bytes(index.storage) + 4 * 1.1 * hnsw.nb_neighbors(0) + 8
    extra = 8 if getattr(index, "invlists", None) is not None else 0
    return float(getattr(index, "code_size", 4 * index.d) + extra)


def train_size(index: Any, n: int) -> int:
    """How many of ``n`` vectors ``index`` is trained on: all of them up to ``max(256 · nlist, 65536)``
    (FAISS's k-means uses at most 256 points per list; PQ codebooks want 65,536)."""
    import faiss

    ivf = faiss.try_extract_index_ivf(index)
    return min(n, max(TRAIN_PER_LIST * (ivf.nlist if ivf is not None else 0), 65536))


def sample_rows(x: np.ndarray, n_max: int) -> np.ndarray:
    """Up to ``n_max`` evenly spaced rows of ``x [N, D]`` as float32 ``[n, D]`` (all of them when N <= n_max)."""
    n = len(x)
    idx = np.arange(n) if n <= n_max else np.unique(np.linspace(0, n - 1, n_max).round().astype(np.int64))
    rows = take_rows(x, idx) if isinstance(x, np.ndarray) else to_numpy(x[idx])  # memory maps: pages released
    return np.ascontiguousarray(rows, dtype=np.float32)


def train_index(index: Any, sample: np.ndarray, conf: AnnConfig, n: int) -> None:
    """Train ``index`` (sized for ``n`` vectors) on ``sample [S, D]``; a deterministic k-means for IVF."""
    import faiss

    ivf = faiss.try_extract_index_ivf(index)
    if ivf is not None:
        ivf.cp.seed = conf.seed  # deterministic k-means of the coarse quantiser
    try:
        index.train(sample)
    except RuntimeError as e:
        raise ConfigError(f"FAISS cannot train index {conf.factory(sample.shape[1], n)!r} on {len(sample)} vectors "
                          f"({str(e).strip().splitlines()[-1][:160]}); hint: fewer lists or codes") from e


def set_search_params(index: Any, conf: AnnConfig) -> None:
    """Apply the search-time settings (``nprobe``, ``efSearch``) of ``conf`` to ``index``."""
    import faiss

    ivf = faiss.try_extract_index_ivf(index)
    if ivf is not None:
        ivf.nprobe = min(conf.nprobe, ivf.nlist)
    hnsw = _hnsw_of(index)
    if hnsw is not None:
        hnsw.efSearch = conf.ef_search


def search(index: Any, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(distances [M, k], ids [M, k])``, ascending Euclidean distance; ``-1`` ids where fewer than k are found."""
    k = check_int("k", k, 1)
    dist, ids = index.search(np.ascontiguousarray(query, dtype=np.float32), min(k, index.ntotal))
    return np.sqrt(np.maximum(dist, 0.0)), ids.astype(np.int64)


def save_index(index: Any, path: str | Path) -> Path:
    """Write ``index`` with ``faiss.write_index`` (atomically)."""
    import faiss

    from ..security.files import atomic_path

    with atomic_path(path) as tmp:
        try:
            faiss.write_index(index, str(tmp))
        except RuntimeError as e:  # faiss reports a failed write (e.g. a full disk) this way
            raise ResourceError(f"cannot write FAISS index {path} ({str(e).strip().splitlines()[-1][:160]}); "
                                "hint: check the free space") from e
    return Path(path)


def load_index(path: str | Path, conf: AnnConfig | None = None) -> Any:
    """Read an index written by :func:`save_index` (search settings from ``conf`` when given)."""
    import faiss

    try:
        index = faiss.read_index(str(path))
    except RuntimeError as e:
        raise CheckpointError(f"cannot read FAISS index {path} ({str(e).splitlines()[0][:200]})") from e
    if conf is not None:
        set_search_params(index, conf)
    return index


def shortlist_recall(approx: np.ndarray, exact: np.ndarray) -> float:
    """Mean fraction of each row of the exact top-K ``exact [M, K]`` found in ``approx [M, K']``."""
    if exact.size == 0:
        return float("nan")
    hits = [len(np.intersect1d(a[a >= 0], e)) / len(e) for a, e in zip(approx, exact, strict=True)]
    return float(np.mean(hits))
