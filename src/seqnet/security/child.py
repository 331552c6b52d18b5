"""The child side of :mod:`seqnet.security.sandbox`: read one request, run its reader, answer.

The request is one JSON line on stdin, ``{"op": NAME, ...}``; the answer is one JSON line on stdout
(the reader's result, or ``{"error": message}`` when it refused the input) followed by the bytes the
result announces. Readers: :data:`READERS` (HDF5 files, FAISS indexes; MAT files have their own child, :mod:`.matlab`).
"""

from __future__ import annotations

import json
import sys
from typing import IO, Any

from ..core.errors import SeqnetError
from .sandbox import answer


def _hdf5(request: dict[str, Any], out: IO[bytes]) -> None:
    from .hdf5_child import dump

    dump(request, out)


def _faiss(request: dict[str, Any], out: IO[bytes]) -> None:
    from .faiss_child import probe

    probe(request, out)


READERS = {"hdf5": _hdf5, "faiss": _faiss}


def main() -> None:
    """Serve one request from stdin (module docstring)."""
    out = sys.stdout.buffer
    try:
        request = json.loads(sys.stdin.buffer.readline())
        READERS[request.pop("op")](request, out)
    except SeqnetError as e:
        answer(out, {"error": " ".join(str(e).split())})
    except Exception as e:  # noqa: BLE001 - any other failure of the library on this input: said, not raised
        answer(out, {"failed": f"{type(e).__name__}: {' '.join(str(e).split())[:300]}"})
    out.flush()
