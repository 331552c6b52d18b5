"""Reading pickles that can neither import nor crash: ground truth made by other VPR tools.

VPR-Bench's ``ground_truth_new.npy`` is ``np.save`` of an object array (rows ``[query_index, reference_indices]``);
users also bring plain pickles of lists, ranges and sets (protocols 0-5, Python 2 byte strings). ``pickle.load``
runs whatever names a file holds, and allowing numpy alone is still unsafe: numpy's ``dtype.__setstate__`` trusts
its state and a crafted one crashes the process (SIGSEGV). So no unpickler runs: opcodes are decoded with
:mod:`pickletools`' table and argument readers (as ``genops``: nothing is executed) and run on this module's own
stack machine, a loop without recursion. Accepted: None, bool, int, float, str, bytes, bytearray, list, tuple, dict,
set, frozenset, ``range``, NumPy arrays (bool, integer, float, object) and scalars. No name is imported: those
numpy and the pickler write for these (``numpy.dtype``, ``numpy._core.multiarray._reconstruct``, ``_codecs.encode``
...) are inert tokens for this module's builders (``np.dtype(code)``, ``np.frombuffer``; never numpy's
``__setstate__``). Refused, naming the file: other names (``os.system``, a user's class), opcodes that look up or
build objects (``INST``, ``NEWOBJ``, persistent ids, extensions, buffers), record, string or date dtypes, integers
past +-2**63, more materialised elements (range lengths, array sizes) than ``16 * len(data) + 10**6``, unhashable
keys, and every malformed or truncated stream.
"""

from __future__ import annotations

import codecs
import io
import math
import os
import pickletools
import re
import struct
from collections import namedtuple
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NoReturn

import numpy as np

from ..core.errors import DatasetError, SeqnetError
from .arrays import read_header
from .inputs import open_input

MAX_FILE_BYTES = 1 << 30
INT_LIMIT = 1 << 63
MAX_KEY_ITEMS = 64
MAX_DIMS = 64
_DTYPE_CODE = re.compile(r"(?:[iu][1248]|f[248]|b1|O[48])\Z")
_NUMPY = ("numpy.core", "numpy._core")
_ALLOWED: dict[tuple[str, str], str] = {
    **{(f"{m}.multiarray", n): n.strip("_") for m in _NUMPY for n in ("_reconstruct", "scalar")},
    **{(f"{m}.numeric", "_frombuffer"): "frombuffer" for m in _NUMPY}, ("numpy", "ndarray"): "ndarray",
    ("numpy", "dtype"): "dtype", ("_codecs", "encode"): "encode", ("builtins", "range"): "range",
    ("__builtin__", "xrange"): "range", ("__builtin__", "range"): "range",
    **{(m, n): n for m in ("builtins", "__builtin__") for n in ("set", "frozenset", "bytearray", "bytes")}}
_VALUES = frozenset("INT BININT BININT1 BININT2 LONG LONG1 LONG4 FLOAT BINFLOAT STRING BINSTRING SHORT_BINSTRING "
                    "UNICODE BINUNICODE SHORT_BINUNICODE BINUNICODE8 BINBYTES SHORT_BINBYTES BINBYTES8 "
                    "BYTEARRAY8".split())
_CONSTANTS: dict[str, Callable[[], Any]] = {
    "NONE": lambda: None, "NEWTRUE": lambda: True, "NEWFALSE": lambda: False, "EMPTY_LIST": list,
    "EMPTY_DICT": dict, "EMPTY_SET": set, "EMPTY_TUPLE": tuple}
_KEY_TYPES = (str, bytes, int, float, type(None), np.generic)
_MALFORMED = (LookupError, TypeError, ValueError, OverflowError, AttributeError, MemoryError, RecursionError,
              struct.error, EOFError)
# an allowed name (kind: what it builds) or, kind "args", a tuple holding names: inert, only builders act on it
_Token = namedtuple("_Token", "kind name items", defaults=("", ()))


@dataclass(eq=False)
class _Pending:
    """An array or dtype made by REDUCE, waiting for its state (BUILD); ``keys``: its memo indexes."""
    kind: str
    code: str = ""
    value: Any = None
    keys: list[int] = field(default_factory=list)


def _what(x: Any) -> str:
    return f"a NumPy {x.kind}" if type(x) is _Pending else type(x).__name__ if type(x) is not _Token else \
        "a tuple holding names" if x.kind == "args" else f"the name {x.name}"


def _short(x: object) -> str:
    return " ".join(str(x)[:200].split())[:120] if isinstance(x, (str, int, bool, type(None))) else _what(x)


class _Loader:
    """The stack machine of one :func:`load_pickle`; ``need(ok, what)`` refuses with ``what`` unless ``ok``."""

    def __init__(self, data: bytes, where: str, error: type[SeqnetError]) -> None:
        self.data, self.where, self.error, self.budget = data, where, error, 16 * len(data) + 10**6
        self.stack: list[Any] = []
        self.marks: list[list[Any]] = []
        self.memo: dict[int, Any] = {}

    def need(self, ok: bool, what: str) -> None:
        if not ok:
            raise self.error(f"cannot read {self.where} as a pickle: {what}")

    def spend(self, n: int, what: str) -> None:
        self.need(n <= self.budget, f"{what} has {n} elements, more than a file of {len(self.data)} bytes may hold")
        self.budget -= n

    def run(self) -> Any:
        """Each opcode decoded as ``pickletools.genops`` does (its table and readers; a protocol-0 STRING as latin-1,
        which genops refuses for Python 2 byte strings), then run, up to STOP."""
        f = io.BytesIO(self.data)
        while code := f.read(1):
            op = pickletools.code2op.get(code.decode("latin-1"))
            self.need(op is not None, f"byte {code!r} at offset {f.tell() - 1} is not a pickle opcode")
            try:
                arg = codecs.escape_decode(pickletools.read_stringnl(f, decode=False))[0].decode("latin-1") \
                    if op.name == "STRING" else None if op.arg is None else op.arg.reader(f)
            except _MALFORMED as e:
                self.need(False, f"opcode {op.name} before offset {f.tell()} is malformed ({_short(str(e))})")
            if op.name in _VALUES:
                self.need(type(arg) is not int or -INT_LIMIT <= arg < INT_LIMIT, "an integer of "
                          f"{arg.bit_length() if type(arg) is int else 0} bits is too large to be an index")
                self.stack.append(arg)
            elif op.name in _CONSTANTS:
                self.stack.append(_CONSTANTS[op.name]())
            elif op.name == "STOP":
                return self.plain(self.pop()[0])
            else:
                self.need(op.name in _HANDLERS, f"refusing opcode {op.name}: only plain data and NumPy arrays are read")
                _HANDLERS[op.name](self, arg)
        self.need(False, "it ends before its STOP opcode (truncated)")

    def pop(self, n: int = 1) -> list[Any]:
        self.need(len(self.stack) >= n, "an opcode finds too few items on the stack (malformed pickle)")
        items, self.stack[len(self.stack) - n:] = self.stack[len(self.stack) - n:], []
        return items

    def pop_mark(self) -> list[Any]:
        self.need(bool(self.marks), "an opcode needs a MARK that is not there (malformed pickle)")
        items, self.stack = self.stack, self.marks.pop()
        return items

    def top(self, kind: type = object) -> Any:
        self.need(bool(self.stack) and isinstance(self.stack[-1], kind), f"an opcode expects a {kind.__name__} on "
                  f"the stack, not {_what(self.stack[-1]) if self.stack else 'nothing'}")
        return self.stack[-1]

    def plain(self, x: Any, tokens: bool = False) -> Any:
        """``x`` as a value (a holder gives its built array or dtype); a name only where ``tokens``."""
        self.need(type(x) is not _Pending or x.value is not None, f"{_what(x)} is used before its state is set")
        self.need(type(x) is not _Token or (tokens and x.kind != "args"), f"{_what(x)} is used as a value")
        return x.value if type(x) is _Pending else x

    def key(self, x: Any) -> Any:
        """``x`` if hashable plain data: a scalar, or a tuple of at most 64 of them in all."""
        todo, seen = [self.plain(x)], 0
        while todo:
            y, seen = todo.pop(), seen + 1
            todo.extend(y if type(y) is tuple else ())
            self.need(type(y) is tuple or isinstance(y, _KEY_TYPES), f"a dict key or set member is {_what(y)}")
            self.need(seen <= MAX_KEY_ITEMS, f"a dict key or set member is a tuple of over {MAX_KEY_ITEMS} items")
        return self.plain(x)

    def remember(self, k: int, v: Any) -> None:
        self.need(k >= 0, f"memo index {k} is negative")
        self.memo[int(k)] = v
        if type(v) is _Pending and v.value is None:
            v.keys.append(int(k))

    def push_tuple(self, items: list[Any]) -> None:
        t = tuple(self.plain(x, tokens=True) for x in items)
        self.stack.append(_Token("args", items=t) if any(type(x) is _Token for x in t) else t)

    def setitems(self, d: dict[Any, Any], items: list[Any]) -> None:
        self.need(len(items) % 2 == 0, "a dict is given an odd number of keys and values")
        for i in range(0, len(items), 2):
            d[self.key(items[i])] = self.plain(items[i + 1])

    def glob(self, module: Any, name: Any) -> None:
        kind = _ALLOWED.get((module, name)) if type(module) is str and type(name) is str else None
        self.need(kind is not None, f"refusing {_short(module)}.{_short(name)}: only plain data and NumPy arrays "
                  "are read")
        self.stack.append(_Token(kind, f"{module}.{name}"))

    def reduce(self) -> None:
        func, args = self.pop(2)
        self.need(type(func) is _Token and func.kind in _BUILDERS, f"refusing to call {_what(func)}")
        self.need(type(args) is tuple or (type(args) is _Token and args.kind == "args"),
                  f"{func.name} is called with {_what(args)}, not a tuple")
        self.stack.append(_BUILDERS[func.kind](self, args if type(args) is tuple else args.items))

    def build(self) -> None:
        state, target = self.plain(self.pop()[0]), self.top()
        self.need(type(target) is _Pending and target.value is None, f"refusing to set the state of "
                  f"{_what(target)}: only NumPy arrays and dtypes are built")
        target.value = (_build_dtype if target.kind == "dtype" else _build_array)(self, target, state)
        self.stack[-1] = target.value
        for k in target.keys:  # the memo's references to the holder, each replaced in O(1)
            if self.memo.get(k) is target:
                self.memo[k] = target.value


_HANDLERS: dict[str, Callable[[_Loader, Any], Any]] = {  # (lambda v: ...)(pop...) pops before ld.stack is read
    "PROTO": lambda ld, a: ld.need(a <= 5, f"protocol {a} is not known"), "FRAME": lambda ld, a: None,
    "MARK": lambda ld, a: (ld.marks.append(ld.stack), setattr(ld, "stack", [])),
    "POP": lambda ld, a: ld.pop() if ld.stack else ld.pop_mark(), "POP_MARK": lambda ld, a: ld.pop_mark(),
    "DUP": lambda ld, a: ld.stack.append(ld.top()),
    "APPEND": lambda ld, a: (lambda v: ld.top(list).append(v))(ld.plain(ld.pop()[0])),
    "APPENDS": lambda ld, a: (lambda v: ld.top(list).extend(v))([ld.plain(x) for x in ld.pop_mark()]),
    "LIST": lambda ld, a: (lambda v: ld.stack.append(v))([ld.plain(x) for x in ld.pop_mark()]),
    "TUPLE": lambda ld, a: ld.push_tuple(ld.pop_mark()), "TUPLE1": lambda ld, a: ld.push_tuple(ld.pop(1)),
    "TUPLE2": lambda ld, a: ld.push_tuple(ld.pop(2)), "TUPLE3": lambda ld, a: ld.push_tuple(ld.pop(3)),
    "DICT": lambda ld, a: (lambda d, m: (ld.setitems(d, m), ld.stack.append(d)))({}, ld.pop_mark()),
    "SETITEM": lambda ld, a: (lambda kv: ld.setitems(ld.top(dict), kv))(ld.pop(2)),
    "SETITEMS": lambda ld, a: (lambda kv: ld.setitems(ld.top(dict), kv))(ld.pop_mark()),
    "ADDITEMS": lambda ld, a: (lambda v: ld.top(set).update(v))([ld.key(x) for x in ld.pop_mark()]),
    "FROZENSET": lambda ld, a: (lambda v: ld.stack.append(frozenset(v)))([ld.key(x) for x in ld.pop_mark()]),
    **{op: lambda ld, a: (ld.need(a in ld.memo, f"memo index {a} is read before it is stored"),
                          ld.stack.append(ld.memo[a])) for op in ("GET", "BINGET", "LONG_BINGET")},
    **{op: lambda ld, a: ld.remember(a, ld.top()) for op in ("PUT", "BINPUT", "LONG_BINPUT")},
    "MEMOIZE": lambda ld, a: ld.remember(len(ld.memo), ld.top()),
    "GLOBAL": lambda ld, a: ld.glob(*a.partition(" ")[::2]), "STACK_GLOBAL": lambda ld, a: ld.glob(*ld.pop(2)),
    "REDUCE": lambda ld, a: ld.reduce(), "BUILD": lambda ld, a: ld.build()}


def _numbers(ld: _Loader, raw: Any, dtype: Any, shape: Any) -> np.ndarray:
    """The flat items for ``shape`` (its size spent from the budget first) of a numeric ``dtype`` made here, from
    exactly as many bytes as they need (for an object dtype nothing: the caller reads a list)."""
    ld.need(type(shape) is tuple and len(shape) <= MAX_DIMS and all(type(s) is int and s >= 0 for s in shape),
            f"an array has the shape {_short(shape)}, not a tuple of at most {MAX_DIMS} sizes")
    ld.spend(n := math.prod(shape), f"an array of shape {shape}")
    ld.need(isinstance(dtype, np.dtype), f"numbers come with {_what(dtype)}, not a NumPy dtype")
    raw = raw.encode("latin-1") if type(raw) is str else raw  # Python 2 byte strings
    if dtype.hasobject:
        return np.empty(0)
    got = len(raw) if type(raw) in (bytes, bytearray) else _what(raw)
    ld.need(got == n * dtype.itemsize, f"{n} items of {dtype} need {n * dtype.itemsize} bytes, the file has {got}")
    flat = np.frombuffer(raw, dtype=dtype, count=n) if n else np.empty(0, dtype=dtype)
    return flat.view(np.uint8) != 0 if dtype.kind == "b" else flat


def _build_dtype(ld: _Loader, target: _Pending, state: Any) -> np.dtype:
    """numpy's dtype state ``(3|4, endian, None, None, None, elsize, align, flags[, metadata])``: the endian only."""
    ld.need(type(state) is tuple and len(state) in (8, 9) and state[0] in (3, 4) and state[1] in ("<", ">", "|", "=")
            and all(type(x) is int for x in state[5:8]), f"the NumPy dtype {target.code} has an unknown state")
    ld.need(all(x is None for x in state[2:5]), f"refusing a NumPy dtype {target.code} with sub-arrays, names or "
            "fields: only plain numbers are read")
    dtype = np.dtype(object) if target.code[0] == "O" else np.dtype(target.code)
    return dtype.newbyteorder(state[1]) if state[1] in "<>" and dtype.kind != "O" and dtype.itemsize > 1 else dtype


def _build_array(ld: _Loader, target: _Pending, state: Any) -> np.ndarray:
    """numpy's array state ``([version,] shape, dtype, is_fortran, rawdata)``; numbers come out native-endian,
    as numpy's ``__setstate__`` makes them, and object items are read from a list in C order."""
    ld.need(type(state) is tuple and len(state) in (4, 5) and (len(state) == 4 or type(state[0]) is int),
            f"a NumPy array has a state this reader does not know ({_what(state)})")
    shape, dtype, fortran, raw = state[-4:]
    flat = _numbers(ld, raw, dtype, shape)
    if not dtype.hasobject:
        return flat.reshape(shape, order="F" if fortran else "C").astype(flat.dtype.newbyteorder("="), order="K")
    ld.need(type(raw) is list and len(raw) == math.prod(shape), f"an object array of shape {shape} needs a list of "
            f"{math.prod(shape)} items, not {_what(raw)}")
    out = np.fromiter(raw, dtype=object, count=len(raw)).reshape(shape)
    return np.asfortranarray(out) if fortran and out.ndim > 1 else out


def _frombuffer(ld: _Loader, a: tuple[Any, ...]) -> np.ndarray:
    """numpy's protocol-5 form ``_frombuffer(buffer, dtype, shape, order[, axis_order])``."""
    ld.need(len(a) in (4, 5) and a[3] in ("C", "F", "K") and (a[3] != "K" or len(a) == 5) and not (
        isinstance(a[1], np.dtype) and a[1].hasobject), "numpy's _frombuffer is called with other than (buffer, "
            "numeric dtype, shape, order[, axis_order])")
    flat = _numbers(ld, a[0], a[1], a[2])
    if a[3] != "K":
        return np.array(flat.reshape(a[2], order=a[3]), order="K")
    ld.need(type(a[4]) is tuple and sorted(a[4]) == list(range(len(a[2]))), f"a bad axis order {_short(a[4])}")
    return np.array(flat.reshape(a[2]).transpose(a[4]), order="K")


def _simple(kind: str) -> Callable[[_Loader, tuple[Any, ...]], Any]:
    """The builder of ``kind``: numpy's _reconstruct, dtype or scalar, range, _codecs.encode, set, frozenset, bytes
    or bytearray (of a list, bytes or latin-1 text), each checking its arguments first."""
    def build(ld: _Loader, a: tuple[Any, ...]) -> Any:
        n, items = len(a), (a[0] if a else [])
        ok = {"reconstruct": lambda: n == 3 and type(a[0]) is _Token and a[0].kind == "ndarray" and type(a[1]) is
              tuple and type(a[2]) in (bytes, str), "dtype": lambda: 1 <= n <= 3 and type(a[0]) is str and
              bool(_DTYPE_CODE.match(a[0])), "scalar": lambda: n == 2 and isinstance(a[0], np.dtype) and
              not a[0].hasobject, "encode": lambda: n == 2 and type(a[0]) is str and a[1] in ("latin1", "latin-1"),
              "range": lambda: 1 <= n <= 3 and all(type(x) is int for x in a) and (n < 3 or a[2] != 0)}.get(
            kind, lambda: n <= 1 and type(items) in (list, tuple, set, frozenset, str, bytes, bytearray)
            or (n == 2 and type(items) is str and a[1] in ("latin1", "latin-1")))
        ld.need(ok(), f"refusing {kind}({_short(a)}): only bool, integer, float and object NumPy dtypes, numeric "
                "scalars, integer ranges, and sets and bytes of lists are read")
        if kind in ("set", "frozenset"):
            return (set if kind == "set" else frozenset)(ld.key(x) for x in items)
        if kind in ("bytes", "bytearray", "encode"):
            return (bytearray if kind == "bytearray" else bytes)(items.encode("latin-1") if n == 2 else items)
        if kind == "range":
            r = range(*a)
            ld.spend(max(0, (r.stop - r.start + r.step - (1 if r.step > 0 else -1)) // r.step), f"the range {r}")
            return r
        return _Pending("array") if kind == "reconstruct" else _Pending("dtype", a[0]) if kind == "dtype" else \
            _numbers(ld, a[1], a[0], ())[0]
    return build


_BUILDERS: dict[str, Callable[[_Loader, tuple[Any, ...]], Any]] = {"frombuffer": _frombuffer, **{
    k: _simple(k) for k in ("reconstruct", "dtype", "scalar", "range", "encode", "set", "frozenset", "bytes",
                            "bytearray")}}


def load_pickle(data: bytes, where: str, error: type[SeqnetError] = DatasetError) -> Any:
    """The plain data or NumPy arrays pickled in ``data`` (module docstring); ``error``, naming ``where``, for
    anything refused or malformed. Nothing is imported or called but this module's builders."""
    try:
        return _Loader(data, where, error).run()
    except SeqnetError:
        raise
    except _MALFORMED as e:
        raise error(f"cannot read {where} as a pickle: it is malformed ({type(e).__name__}: {_short(str(e))})") from e


def load_npy_objects(path: str | os.PathLike[str], where: str | None = None,
                     error: type[SeqnetError] = DatasetError) -> Any:
    """The object array of an ``np.save(..., allow_pickle=True)`` file, checked against its header's shape, or
    the value of a file that is one whole pickle (VPR-Bench users' ``.pkl``); at most :data:`MAX_FILE_BYTES`."""
    where, shape = where or str(path), None
    with open_input(path, "file", error) as f:
        if (size := os.fstat(f.fileno()).st_size) > MAX_FILE_BYTES:
            raise error(f"cannot read {where}: it has {size} bytes, more than the {MAX_FILE_BYTES} read here")
        npy = f.read(6) == b"\x93NUMPY"
        f.seek(0)
        if npy:
            shape, _, dtype = read_header(f, where, error)
            if dtype != np.dtype(object):
                raise error(f"cannot read {where} as pickled objects: it is a .npy array of {dtype}, not of objects "
                            "(read it as a numeric array)")
        data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES or not data:
        raise error(f"cannot read {where}: it grew past {MAX_FILE_BYTES} bytes while it was read" if data else
                    f"cannot read {where}: it is empty" if shape is None else
                    f"cannot read {where}: its .npy header is not followed by pickled objects")
    out = load_pickle(data, where, error)
    if shape is not None and (not isinstance(out, np.ndarray) or out.shape != shape):
        got = f"an array of shape {out.shape}" if isinstance(out, np.ndarray) else type(out).__name__
        raise error(f"cannot read {where}: its .npy header declares shape {shape} but its pickle holds {got}")
    return out
