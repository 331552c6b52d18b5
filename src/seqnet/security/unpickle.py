"""Reading pickles that can neither import nor crash: ground truth made by other VPR tools.

VPR-Bench's ``ground_truth_new.npy`` (``np.save`` of an object array of ``[query, references]`` rows) and users'
plain pickles (lists, ranges, sets; protocols 0-5; Python 2) are read without an unpickler: ``pickle.load`` runs
any name in a file, and allowing numpy alone is unsafe too (a crafted state crashes numpy's ``dtype.__setstate__``).
Opcodes are decoded by :mod:`pickletools`' table and readers (as ``genops``; nothing runs) and run on this module's
stack machine (a loop: no recursion). Accepted: None, bool, int, float, str, bytes, bytearray, list, tuple, dict,
set, frozenset, range, NumPy arrays (bool, int, float, object) and scalars. No name is imported: the few numpy
and the pickler write (``numpy.dtype``, ``_codecs.encode`` ...) are inert tokens for this module's builders
(``np.dtype(code)``, ``np.frombuffer``; never numpy's ``__setstate__``). Refused, naming the file: other names
(``os.system``, a user's class), opcodes that look up or build objects (``INST``, ``NEWOBJ``, ``PERSID``, ``EXT1``,
buffers), record, string or date dtypes, integers past +-2**63, more materialised elements (range lengths, array
sizes) than ``16 * len(data) + 10**6``, unhashable keys, and malformed or truncated streams.
"""

from __future__ import annotations

import codecs
import io
import math
import os
import pickletools
import re
import reprlib
import struct
from collections import namedtuple
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, NoReturn

import numpy as np

from ..core.errors import DatasetError, SeqnetError
from .arrays import read_header
from .inputs import open_input

MAX_FILE_BYTES = 1 << 30
INT_LIMIT = 1 << 63
MAX_ITEMS = 64  # at most this many dimensions in an array, items in a dict key (a tuple) or set member
_DTYPE_CODE = re.compile(r"(?:[iu][1248]|f[248]|b1|O[48])\Z")
_ALLOWED: dict[tuple[str, str], str] = {  # (module, name): what it builds
    **{(f"numpy.{c}.{m}", n): n.strip("_") for c in ("core", "_core") for m, n in (("multiarray", "_reconstruct"),
       ("multiarray", "scalar"), ("numeric", "_frombuffer"))}, ("numpy", "ndarray"): "ndarray",
    ("numpy", "dtype"): "dtype", ("_codecs", "encode"): "encode", ("__builtin__", "xrange"): "range",
    **{(m, n): n for m in ("builtins", "__builtin__") for n in ("set", "frozenset", "bytearray", "bytes", "range")}}
_VALUES = frozenset(("INT BININT BININT1 BININT2 LONG LONG1 LONG4 FLOAT BINFLOAT STRING BINSTRING SHORT_BINSTRING "
                     "UNICODE BINUNICODE SHORT_BINUNICODE BINUNICODE8 BINBYTES SHORT_BINBYTES BINBYTES8 "
                     "BYTEARRAY8").split())  # opcodes pushing their argument
_CONSTANTS: dict[str, Callable[[], Any]] = dict(NONE=type(None), NEWTRUE=lambda: True, NEWFALSE=bool, EMPTY_LIST=list,
                                                EMPTY_DICT=dict, EMPTY_SET=set, EMPTY_TUPLE=tuple)
_OPCODES: dict[bytes, tuple[str, Callable[[Any], Any] | None]] = {  # code: (name, argument reader), as genops
    op.code.encode("latin-1"): (op.name, (lambda f: codecs.escape_decode(pickletools.read_stringnl(f, decode=False))[
        0].decode("latin-1")) if op.name == "STRING" else op.arg and op.arg.reader) for op in pickletools.opcodes}
_ONLY = "only plain data and NumPy arrays are read"
_KEY_TYPES = (str, bytes, int, float, type(None), np.generic)
_MALFORMED = (LookupError, TypeError, ValueError, ArithmeticError, AttributeError, MemoryError, RecursionError,
              struct.error)
_Token = namedtuple("_Token", "kind name items", defaults=("", ()))  # an allowed name, or ("args") a tuple of some
_Pending = SimpleNamespace  # kind, code, value (None until BUILD), keys (its memo indexes): an array or dtype


def _what(x: Any) -> str:
    return f"a NumPy {x.kind}" if type(x) is _Pending else type(x).__name__ if type(x) is not _Token else \
        "a tuple holding names" if x.kind == "args" else f"the name {x.name}"


def _short(x: object) -> str:
    return " ".join((x[:200] if type(x) is str else reprlib.repr(x)).split())[:120]


class _Loader:
    """The stack machine of one :func:`load_pickle`; ``ok or self.fail(what)`` formats ``what`` on failure only."""

    def __init__(self, data: bytes, where: str, error: type[SeqnetError]) -> None:
        self.data, self.where, self.error, self.budget = data, where, error, 16 * len(data) + 10**6
        self.stack, self.marks, self.memo = [], [], {}

    def fail(self, what: str) -> NoReturn:
        raise self.error(f"cannot read {self.where} as a pickle: {what}")

    def spend(self, n: int, what: str) -> None:
        n <= self.budget or self.fail(f"{what} has {n} elements, more than a file of {len(self.data)} bytes may hold")
        self.budget -= n

    def run(self) -> Any:
        """Each opcode decoded as by ``genops`` (but a STRING as latin-1, as Python 2 made it), run, up to STOP."""
        f = io.BytesIO(self.data)
        while code := f.read(1):
            name, read = _OPCODES.get(code) or self.fail(f"byte {code!r} at offset {f.tell() - 1} is not an opcode")
            arg = read(f) if read else None  # ValueError when malformed
            if name in _VALUES:
                if type(arg) is int and not -INT_LIMIT <= arg < INT_LIMIT:
                    self.fail(f"an integer of {arg.bit_length()} bits is too large to be an index")
                self.stack.append(arg)
            elif name in _CONSTANTS:
                self.stack.append(_CONSTANTS[name]())
            elif name == "STOP":
                return self.plain(self.pop()[0])
            else:
                (_HANDLERS.get(name) or self.fail(f"refusing opcode {name}: {_ONLY}"))(self, arg)
        self.fail("it ends before its STOP opcode (truncated)")

    def pop(self, n: int = 1) -> list[Any]:
        len(self.stack) >= n or self.fail("an opcode finds too few items on the stack (malformed pickle)")
        items, self.stack[len(self.stack) - n:] = self.stack[len(self.stack) - n:], []
        return items

    def pop_mark(self) -> list[Any]:
        self.marks or self.fail("an opcode needs a MARK that is not there (malformed pickle)")
        items, self.stack = self.stack, self.marks.pop()
        return items

    def top(self, kind: type = object) -> Any:
        bool(self.stack) and isinstance(self.stack[-1], kind) or self.fail(f"an opcode expects a {kind.__name__}")
        return self.stack[-1]

    def plain(self, x: Any, tokens: bool = False) -> Any:
        """``x`` as a value (a holder gives its built array or dtype); a name only where ``tokens``."""
        type(x) is not _Pending or x.value is not None or self.fail(f"{_what(x)} is used before its state is set")
        type(x) is not _Token or (tokens and x.kind != "args") or self.fail(f"{_what(x)} is used as a value")
        return x.value if type(x) is _Pending else x

    def key(self, x: Any) -> Any:
        """``x`` if hashable plain data: a scalar, or a tuple of at most 64 of them in all."""
        todo, seen = [self.plain(x)], 0
        while todo:
            y, seen = todo.pop(), seen + 1
            todo.extend(y if type(y) is tuple else ())
            type(y) is tuple or isinstance(y, _KEY_TYPES) or self.fail(f"a dict key or set member is {_what(y)}")
            seen <= MAX_ITEMS or self.fail(f"a dict key or set member is a tuple of over {MAX_ITEMS} items")
        return self.plain(x)

    def remember(self, k: int, v: Any) -> None:
        k >= 0 or self.fail(f"memo index {k} is negative")
        self.memo[k] = v
        if type(v) is _Pending and v.value is None:
            v.keys.append(k)

    def push_tuple(self, items: list[Any]) -> None:
        t = tuple(self.plain(x, tokens=True) for x in items)
        self.stack.append(_Token("args", items=t) if any(type(x) is _Token for x in t) else t)

    def setitems(self, d: dict[Any, Any], items: list[Any]) -> None:
        len(items) % 2 == 0 or self.fail("a dict is given an odd number of keys and values")
        d.update((self.key(k), self.plain(v)) for k, v in zip(items[::2], items[1::2], strict=True))

    def glob(self, module: Any, name: Any) -> None:
        kind = _ALLOWED.get((module, name)) if type(module) is str and type(name) is str else None
        kind or self.fail(f"refusing {_short(module)}.{_short(name)}: {_ONLY}")
        self.stack.append(_Token(kind, f"{module}.{name}"))

    def reduce(self) -> None:
        func, args = self.pop(2)
        type(func) is _Token and func.kind in _BUILDERS or self.fail(f"refusing to call {_what(func)}")
        type(args) is tuple or (type(args) is _Token and args.kind == "args") or self.fail(f"{func.name} without args")
        args = args if type(args) is tuple else args.items
        _ARGS_OK[func.kind](args) or self.fail(f"refusing {func.name}{_short(args)}: {_ONLY} (bool, integer, float "
                                               "or object dtypes; ranges, sets and bytes)")
        self.stack.append(_BUILDERS[func.kind](self, args))

    def build(self) -> None:
        state, target = self.plain(self.pop()[0]), self.top()
        type(target) is _Pending and target.value is None or self.fail(f"refusing to set the state of {_what(target)}")
        target.value = (_build_dtype if target.kind == "dtype" else _build_array)(self, target, state)
        self.stack[-1] = target.value
        self.memo.update({k: target.value for k in target.keys if self.memo.get(k) is target})  # O(1) each


_HANDLERS: dict[str, Callable[[_Loader, Any], Any]] = {  # (lambda v: ...)(pop...) pops before ld.stack is read
    "PROTO": lambda ld, a: a <= 5 or ld.fail(f"protocol {a} is not known"), "FRAME": lambda ld, a: None,
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
    **{op: lambda ld, a: (a in ld.memo or ld.fail(f"memo index {a} is read before it is stored"),
                          ld.stack.append(ld.memo[a])) for op in ("GET", "BINGET", "LONG_BINGET")},
    **{op: lambda ld, a: ld.remember(a, ld.top()) for op in ("PUT", "BINPUT", "LONG_BINPUT")},
    "MEMOIZE": lambda ld, a: ld.remember(len(ld.memo), ld.top()),
    "GLOBAL": lambda ld, a: ld.glob(*a.partition(" ")[::2]), "STACK_GLOBAL": lambda ld, a: ld.glob(*ld.pop(2)),
    "REDUCE": lambda ld, a: ld.reduce(), "BUILD": lambda ld, a: ld.build()}


def _numbers(ld: _Loader, raw: Any, dtype: Any, shape: Any) -> np.ndarray:
    """The flat items (an object dtype: none) for ``shape``, spent from the budget first, from exactly their bytes."""
    (type(shape) is tuple and len(shape) <= MAX_ITEMS and all(type(s) is int and s >= 0 for s in shape)
     or ld.fail(f"an array has the shape {_short(shape)}, not a tuple of at most {MAX_ITEMS} sizes"))
    ld.spend(n := math.prod(shape), f"an array of shape {shape}")
    isinstance(dtype, np.dtype) or ld.fail(f"numbers come with {_what(dtype)}, not a NumPy dtype")
    if dtype.hasobject:
        return np.empty(0)
    raw = raw.encode("latin-1") if type(raw) is str else raw  # Python 2 byte strings
    got = len(raw) if type(raw) in (bytes, bytearray) else _what(raw)
    got == n * dtype.itemsize or ld.fail(f"{n} items of {dtype} need {n * dtype.itemsize} bytes, the file has {got}")
    flat = np.frombuffer(raw, dtype=dtype, count=n) if n else np.empty(0, dtype=dtype)
    return flat.view(np.uint8) != 0 if dtype.kind == "b" else flat


def _build_dtype(ld: _Loader, target: _Pending, state: Any) -> np.dtype:
    """numpy's dtype state ``(3|4, endian, None, None, None, elsize, align, flags[, metadata])``: the endian only."""
    (type(state) is tuple and len(state) in (8, 9) and state[0] in (3, 4) and state[1] in ("<", ">", "|", "=")
     and all(type(x) is int for x in state[5:8]) or ld.fail(f"the NumPy dtype {target.code} has an unknown state"))
    all(x is None for x in state[2:5]) or ld.fail(f"refusing a NumPy dtype {target.code} with sub-arrays or fields")
    dtype = np.dtype(object) if target.code[0] == "O" else np.dtype(target.code)
    return dtype.newbyteorder(state[1]) if state[1] in "<>" and dtype.kind != "O" and dtype.itemsize > 1 else dtype


def _build_array(ld: _Loader, target: _Pending, state: Any) -> np.ndarray:
    """numpy's array state ``([version,] shape, dtype, is_fortran, rawdata)``; numbers made native, as numpy does."""
    (type(state) is tuple and len(state) in (4, 5) and (len(state) == 4 or type(state[0]) is int)
     or ld.fail(f"a NumPy array has a state this reader does not know ({_what(state)})"))
    shape, dtype, fortran, raw = state[-4:]
    flat = _numbers(ld, raw, dtype, shape)
    if not dtype.hasobject:
        return flat.reshape(shape, order="F" if fortran else "C").astype(flat.dtype.newbyteorder("="), order="K")
    type(raw) is list and len(raw) == math.prod(shape) or ld.fail(f"an object array {shape} needs a list of its items")
    out = np.fromiter(raw, dtype=object, count=len(raw)).reshape(shape)
    return np.asfortranarray(out) if fortran and out.ndim > 1 else out


def _frombuffer(ld: _Loader, a: tuple[Any, ...]) -> np.ndarray:
    """numpy's protocol-5 form ``_frombuffer(buffer, dtype, shape, order[, axis_order])``."""
    (a[3] in ("C", "F", "K") and (a[3] != "K" or len(a) == 5) and not (isinstance(a[1], np.dtype) and a[1].hasobject)
     or ld.fail("_frombuffer needs (buffer, numeric dtype, shape, order[, axes])"))
    flat = _numbers(ld, a[0], a[1], a[2])
    a[3] != "K" or (type(a[4]) is tuple and sorted(a[4]) == list(range(len(a[2])))) or ld.fail("a bad axis order")
    return np.array(flat.reshape(a[2], order=a[3]) if a[3] != "K" else flat.reshape(a[2]).transpose(a[4]), order="K")


def _range(ld: _Loader, a: tuple[Any, ...]) -> range:
    r = range(*a)
    ld.spend(max(0, (r.stop - r.start + r.step - (1 if r.step > 0 else -1)) // r.step), f"the range {r}")
    return r


def _items(a: tuple[Any, ...]) -> Any:
    """What set, frozenset, bytes or bytearray is made of: ``(items,)``, ``(text, "latin1")`` or nothing."""
    return a[0].encode("latin-1") if len(a) == 2 else a[0] if a else ()


_ARGS_OK: dict[str, Callable[[tuple[Any, ...]], bool]] = {  # what each builder accepts (_frombuffer: checks more)
    "frombuffer": lambda a: len(a) in (4, 5),
    "reconstruct": lambda a: len(a) == 3 and type(a[0]) is _Token and a[0].kind == "ndarray"
    and type(a[1]) is tuple and type(a[2]) in (bytes, str),
    "dtype": lambda a: 1 <= len(a) <= 3 and type(a[0]) is str and bool(_DTYPE_CODE.match(a[0])),
    "scalar": lambda a: len(a) == 2 and isinstance(a[0], np.dtype) and not a[0].hasobject,
    "range": lambda a: 1 <= len(a) <= 3 and all(type(x) is int for x in a) and (len(a) < 3 or a[2] != 0),
    "encode": lambda a: len(a) == 2 and type(a[0]) is str and a[1] in ("latin1", "latin-1"),
    **dict.fromkeys(("set", "frozenset", "bytes", "bytearray"), lambda a: _ARGS_OK["encode"](a) or (len(a) <= 1
                    and type(a[0] if a else ()) in (list, tuple, set, frozenset, bytes, bytearray)))}
_BUILDERS: dict[str, Callable[[_Loader, tuple[Any, ...]], Any]] = {
    "frombuffer": _frombuffer, "range": _range, "scalar": lambda ld, a: _numbers(ld, a[1], a[0], ())[0],
    "reconstruct": lambda ld, a: _Pending(kind="array", code="", value=None, keys=[]),
    "dtype": lambda ld, a: _Pending(kind="dtype", code=a[0], value=None, keys=[]),
    "set": lambda ld, a: set(ld.key(x) for x in _items(a)),
    "frozenset": lambda ld, a: frozenset(ld.key(x) for x in _items(a)),
    "bytes": lambda ld, a: bytes(_items(a)), "bytearray": lambda ld, a: bytearray(_items(a)),
    "encode": lambda ld, a: _items(a)}


def load_pickle(data: bytes, where: str, error: type[SeqnetError] = DatasetError) -> Any:
    """The data pickled in ``data`` (module docstring); ``error``, naming ``where``, for anything refused."""
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
        magic, _ = f.read(6), f.seek(0)
        if magic == b"\x93NUMPY":
            shape, _, dtype = read_header(f, where, error)
            if dtype != np.dtype(object):
                raise error(f"cannot read {where} as pickled objects: it is a .npy array of {dtype}, not of objects "
                            "(read it as a numeric array)")
        data = f.read(MAX_FILE_BYTES)
    if not data:
        raise error(f"cannot read {where}: {'it is empty' if shape is None else 'no pickle follows its .npy header'}")
    out = load_pickle(data, where, error)
    if shape is not None and not (isinstance(out, np.ndarray) and out.shape == shape):
        raise error(f"cannot read {where}: its .npy header declares shape {shape}, its pickle holds {_what(out)} "
                    f"{getattr(out, 'shape', '')}")
    return out
