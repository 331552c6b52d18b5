"""Reading a FAISS index inside the sandbox's child (:mod:`seqnet.security.sandbox`); the parent side is
:mod:`seqnet.security.faissfile`.

The index is read with its on-disk inverted lists looked up in its own folder and mapped read-only
(``IO_FLAG_READ_ONLY | IO_FLAG_ONDISK_SAME_DIR``: never written); what a search would later
dereference is checked: every HNSW neighbour is a stored vector, every on-disk list lies inside the lists
file; then a few searches run. The answer says what the index is (vectors, D, the on-disk lists file and
its size) for the parent to check before it reads the index itself.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from ..core.errors import DatasetError
from .inputs import open_input
from .sandbox import answer


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """FAISS prints on file descriptor 1 (the answer's channel): point it at /dev/null inside the block."""
    saved = os.dup(1)
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def probe(request: dict[str, Any], out: IO[bytes]) -> None:
    """Answer ``{"ntotal", "d", "kind", "ondisk": {"filename", "totsize"} | None}`` after the checks above."""
    import faiss

    path = str(request["path"])
    with open_input(path, "FAISS index"):
        pass  # a regular file, not a FIFO or device
    flags = faiss.IO_FLAG_READ_ONLY | faiss.IO_FLAG_ONDISK_SAME_DIR
    with quiet_stdout():
        try:
            index = faiss.read_index(path, flags)
        except RuntimeError as e:
            raise DatasetError(f"cannot read FAISS index {path} ({str(e).strip().splitlines()[-1][:200]})") from e
        ondisk = _check_lists(index, path)
        _check_graph(index, path)
        if index.ntotal:
            index.search(np.random.default_rng(0).random((4, index.d), dtype=np.float32), min(10, index.ntotal))
    answer(out, {"ntotal": int(index.ntotal), "d": int(index.d), "ondisk": ondisk,
                 "kind": type(faiss.downcast_index(index)).__name__})


def _check_lists(index: Any, path: str) -> dict[str, Any] | None:
    """The on-disk lists of an IVF index (file and size), each list checked to lie inside them; None when the
    lists are in the index itself."""
    import faiss

    ivf = faiss.try_extract_index_ivf(index)
    if ivf is None:
        return None
    od = faiss.downcast_InvertedLists(ivf.invlists)
    if not isinstance(od, faiss.OnDiskInvertedLists):
        return None
    entry = od.code_size + 8  # a code and its id
    for i in range(od.lists.size()):
        one = od.lists.at(i)
        if one.size > one.capacity or one.offset < 0 or one.offset + one.capacity * entry > od.totsize:
            raise DatasetError(f"{path}: inverted list {i} lies outside its lists file ({one.offset} + "
                               f"{one.capacity} x {entry} > {od.totsize} bytes)")
    return {"filename": str(od.filename), "totsize": int(od.totsize)}


def _check_graph(index: Any, path: str) -> None:
    """Every neighbour of an HNSW graph is one of the stored vectors (or -1), its offsets in order."""
    import faiss

    inner = faiss.downcast_index(index)
    inner = faiss.downcast_index(inner.index) if hasattr(inner, "index") and hasattr(inner, "chain") else inner
    hnsw = getattr(inner, "hnsw", None)
    if hnsw is None:
        return
    neighbors = faiss.vector_to_array(hnsw.neighbors)
    offsets = faiss.vector_to_array(hnsw.offsets)
    levels = faiss.vector_to_array(hnsw.levels)
    if (neighbors.size and (neighbors.min() < -1 or neighbors.max() >= index.ntotal)) or \
            len(offsets) != index.ntotal + 1 or (np.diff(offsets) < 0).any() or \
            (offsets.size and offsets[-1] > neighbors.size) or len(levels) != index.ntotal or \
            not -1 <= hnsw.entry_point < max(index.ntotal, 1):
        raise DatasetError(f"{path}: its HNSW graph names vectors it does not hold (a damaged or crafted index)")
