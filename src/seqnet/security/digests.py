"""File hashes recorded when a dataset or map is written, and checked when it is opened.

The keys of a recorded ``checksums`` mapping are read from a file: each is resolved inside the
folder (:func:`seqnet.security.inputs.inside`) and opened without blocking
(:func:`seqnet.security.inputs.open_input`), so a key ``../x`` or a FIFO is refused, never read.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

from ..core.errors import DatasetError, SeqnetError
from .inputs import inside, open_input

SAMPLE_BLOCK = 4096
SAMPLE_BLOCKS = 16


def file_digest(path: str | os.PathLike[str], full: bool = False) -> dict[str, Any]:
    """``{"size", "sample"}`` of a file: its size and a BLAKE2b hash of its first and last 64 KiB and of
    16 evenly spaced 4 KiB blocks (cheap on a file of any size); with ``full`` also ``"full"``, the hash of
    every byte. The file is opened with :func:`open_input` (a FIFO or device is refused, never read)."""
    with open_input(path, "file") as f:
        size, sample = os.fstat(f.fileno()).st_size, hashlib.blake2b(digest_size=16)
        offsets = [0, max(0, size - 65536), *(int(size * (i + 0.5) / SAMPLE_BLOCKS) for i in range(SAMPLE_BLOCKS))]
        for off, n in zip(offsets, [65536, 65536, *[SAMPLE_BLOCK] * SAMPLE_BLOCKS], strict=True):
            f.seek(off)
            sample.update(f.read(n))
        out = {"size": size, "sample": sample.hexdigest()}
        if full:
            whole = hashlib.blake2b(digest_size=16)
            f.seek(0)
            for chunk in iter(lambda: f.read(1 << 20), b""):
                whole.update(chunk)
            out["full"] = whole.hexdigest()
    return out


def changed_files(root: Path, digests: Any, full: bool = False, error: type[SeqnetError] = DatasetError) -> list[str]:
    """The files of ``digests`` (read from a file in ``root``) that are missing or differ from what
    :func:`file_digest` recorded; ``error`` when the record is malformed or a key leads outside ``root``."""
    if not isinstance(digests, dict) or not all(isinstance(v, dict) for v in digests.values()):
        raise error(f"{root}: the recorded checksums are not a mapping of file -> {{size, sample}}")
    changed = []
    for rel, want in digests.items():
        f = inside(root, rel, f"{root}: checksum of", error)
        deep = full and "full" in want
        got = file_digest(f, deep) if f.is_file() else {}
        if got.get("size") != want.get("size") or got.get("sample") != want.get("sample") or (
                deep and got["full"] != want["full"]):
            changed.append(rel)
    return changed


def verify_digests(root: Path, digests: dict[str, Any], error: type[SeqnetError], what: str, hint: str,
                   full: bool = False) -> None:
    """Every file of ``digests`` (as :func:`file_digest` recorded them when ``root`` was written) is there
    with the same size and sampled hash (``full``: and the same bytes); ``error`` naming the first that is not
    (:func:`changed_files`)."""
    changed = changed_files(root, digests, full, error)
    if changed:
        f = root / changed[0]
        if not f.is_file():
            raise error(f"{f} is missing from the {what} (hint: {hint})")
        raise error(f"{f} changed since the {what} was written ({f.stat().st_size} bytes, "
                    f"{digests[changed[0]].get('size')} then, or other contents); hint: {hint}")
