"""``scipy.io.loadmat`` of a checked ``.mat`` file (:func:`~.matfile.checked_mat`) in a child process.

scipy's MAT reader is Cython written for trusted files; the bytes it gets have been walked and bounded,
but what it might still do wrong on a stranger's file (crash, hang, allocate) happens in a child started
as the sandbox starts its readers (:func:`seqnet.security.sandbox.python_command`: isolated, limited
memory and CPU time, no file written, killed after a timeout). The child answers one JSON line: the
top-level variable names and the fields of one struct variable, each field as numbers, text, or a cell of
them (anything else is described, not sent); the parent rebuilds them as arrays.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from typing import Any

import numpy as np

from ..core.errors import DatasetError
from .matfile import checked_mat
from .sandbox import BASE_MEMORY, child_env, python_command, time_bound

MAX_ANSWER = 1 << 31


def read_struct(path: str | os.PathLike[str], variable: str) -> tuple[list[str], dict[str, np.ndarray] | None]:
    """``(variable names, fields of the struct `variable` or None)`` of a MATLAB v5 file, read in the child;
    a malformed file, or a child that dies or overruns its time, is one :class:`DatasetError` naming it."""
    data = checked_mat(path)
    code = f"from {__name__} import serve\nserve({variable!r})\n"
    timeout = time_bound(len(data))
    try:
        done = subprocess.run(python_command(code, BASE_MEMORY + 8 * len(data), int(timeout) + 1), input=data,
                              capture_output=True, timeout=timeout, env=child_env(), cwd="/", check=False,
                              start_new_session=True)
    except subprocess.TimeoutExpired as e:
        raise DatasetError(f"cannot read {path}: reading it took longer than {timeout:.0f} s") from e
    try:
        answer = json.loads(done.stdout[:MAX_ANSWER]) if done.stdout else None
    except ValueError:
        answer = None
    if not isinstance(answer, dict):
        why = f"the reader crashed on it (signal {-done.returncode})" if done.returncode < 0 else \
            f"the reader failed ({' '.join(done.stderr[-300:].decode('utf-8', 'replace').split())})"
        raise DatasetError(f"cannot read {path} as a MATLAB v5 .mat file: {why}; hint: pass a seqNet "
                           "structFiles/*.db")
    if isinstance(answer.get("error"), str):
        raise DatasetError(f"cannot read {path} as a MATLAB v5 .mat file ({answer['error'][:200]}); hint: pass a "
                           "seqNet structFiles/*.db")
    fields = answer.get("fields")
    decoded = {str(k): decode(v, f"{path}: {variable}.{k}") for k, v in fields.items()} \
        if isinstance(fields, dict) else None
    return [str(v) for v in answer.get("variables") or []], decoded


def decode(value: Any, where: str) -> np.ndarray:
    """A field as the child encoded it (:func:`encode`), as an array (an object array for a cell)."""
    if not isinstance(value, dict) or not isinstance(value.get("shape"), list):
        raise DatasetError(f"{where}: the reader sent {str(value)[:60]}")
    shape = tuple(int(s) for s in value["shape"])
    if "numbers" in value:
        flat = np.asarray(value["numbers"], dtype=np.float64)
    elif "texts" in value:
        flat = np.asarray([str(t) for t in value["texts"]], dtype=str)
    elif "cells" in value:
        flat = np.empty(len(value["cells"]), dtype=object)
        for i, c in enumerate(value["cells"]):
            flat[i] = decode(c, where)
    else:
        return np.empty((0,), dtype=[("unread", "O")])  # not numbers, text or a cell: a type no field takes
    if flat.size != int(np.prod(shape)):
        raise DatasetError(f"{where}: the reader sent {flat.size} values for the shape {shape}")
    return flat.reshape(shape)


def encode(value: Any, depth: int = 0) -> dict[str, Any]:
    """A field of a loaded struct for the JSON answer: numbers, text, a cell of them (two levels), or ``other``."""
    a = np.asarray(value)
    out: dict[str, Any] = {"shape": list(a.shape)}
    if a.dtype.kind in "biuf" and a.dtype.fields is None:
        out["numbers"] = [float(x) for x in a.astype(np.float64).ravel()]
    elif a.dtype.kind == "U":
        out["texts"] = [str(x) for x in a.ravel()]
    elif a.dtype == object and depth < 2:
        out["cells"] = [encode(x, depth + 1) for x in a.ravel()]
    else:
        out["other"] = str(a.dtype)[:80]
    return out


def serve(variable: str) -> None:
    """The child: ``loadmat`` the checked bytes on stdin, answer the variable names and ``variable``'s fields."""
    from scipy.io import loadmat

    out = sys.stdout
    try:
        mat = loadmat(io.BytesIO(sys.stdin.buffer.read()))
        names = [k for k in mat if not k.startswith("__")]
        s = mat.get(variable)
        fields = None
        if isinstance(s, np.ndarray) and s.size and s.dtype.names:
            first = s.ravel()[0]
            fields = {name: encode(first[name]) for name in s.dtype.names}
        json.dump({"variables": names[:100], "fields": fields}, out, allow_nan=True)
    except Exception as e:  # noqa: BLE001 - any failure of scipy on these bytes is the answer, in one line
        json.dump({"error": f"{type(e).__name__}: {' '.join(str(e).split())[:300]}"}, out)
    out.flush()
