"""The pickle reader that neither imports nor crashes (seqnet.security.unpickle).

Plain data and NumPy arrays written by the real pickler / ``np.save`` are read as ``pickle.loads`` reads
them; hand-built hostile streams (made from opcodes here, never given to the real unpickler) are refused
with the caller's error class; truncated and mutated streams give a value or that error, nothing else.
"""

from __future__ import annotations

import io
import math
import os
import pickle
import struct
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.security import unpickle
from seqnet.security.unpickle import load_npy_objects, load_pickle

DTYPES = ["b1", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "f2", "f4", "f8"]
FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ----------------------------------------------------------------------------------------------- helpers


def same(a, b) -> bool:
    """Equal values of the same types all the way down (arrays: dtype, shape, layout and items)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        if (a.dtype.str, a.shape, a.flags.c_contiguous, a.flags.f_contiguous) != \
                (b.dtype.str, b.shape, b.flags.c_contiguous, b.flags.f_contiguous):
            return False
        if a.dtype.hasobject:
            return all(same(x, y) for x, y in zip(a.ravel(order="K"), b.ravel(order="K"), strict=True))
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, np.generic):
        return a.dtype == b.dtype and (a == b or (np.isnan(a) and np.isnan(b)))
    return a == b


def roundtrip(obj, protocol: int):
    """``(ours, pickle.loads)`` of ``obj`` pickled by the real pickler (legitimate data only)."""
    data = pickle.dumps(obj, protocol=protocol)
    return load_pickle(data, "x.pkl"), pickle.loads(data)


def npy_bytes(arr: np.ndarray, protocol: int) -> bytes:
    """``np.save(..., allow_pickle=True)`` of an object array, with the pickle protocol chosen."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, np.lib.format.header_data_from_array_1_0(arr))
    pickle.dump(arr, buf, protocol=protocol)
    return buf.getvalue()


# Hand-built streams: opcodes from the pickle module, arguments encoded here.
def glob(module: str, name: str) -> bytes:
    return pickle.GLOBAL + f"{module}\n{name}\n".encode()


def text(s: str) -> bytes:
    b = s.encode()
    return pickle.BINUNICODE + struct.pack("<I", len(b)) + b


def raw(b: bytes) -> bytes:
    return pickle.BINBYTES + struct.pack("<I", len(b)) + b


def num(n: int) -> bytes:
    return pickle.INT + f"{n}\n".encode()


def tup(*items: bytes) -> bytes:
    return pickle.MARK + b"".join(items) + pickle.TUPLE


def stream(*body: bytes) -> bytes:
    return pickle.PROTO + b"\x03" + b"".join(body) + pickle.STOP


def dstate(endian: str = "<", sub: bytes = pickle.NONE, names: bytes = pickle.NONE, fields: bytes = pickle.NONE,
           version: int = 3) -> bytes:
    """numpy's dtype state tuple ``(version, endian, subarray, names, fields, elsize, align, flags)``."""
    return tup(num(version), text(endian), sub, names, fields, num(-1), num(-1), num(0))


def dtype(code: str, state: bytes | None = None) -> bytes:
    return glob("numpy", "dtype") + tup(text(code), pickle.NEWFALSE, pickle.NEWTRUE) + pickle.REDUCE + \
        (state if state is not None else dstate("|" if code in ("b1", "i1", "u1", "O8") else "<")) + pickle.BUILD


def array(shape: tuple[int, ...], dt: bytes, data: bytes, fortran: bool = False) -> bytes:
    """numpy's ``_reconstruct(ndarray, (0,), b'b')`` then BUILD with ``(1, shape, dtype, fortran, data)``."""
    return glob("numpy.core.multiarray", "_reconstruct") + tup(glob("numpy", "ndarray"), tup(num(0)), raw(b"b")) + \
        pickle.REDUCE + tup(num(1), tup(*map(num, shape)), dt, pickle.NEWTRUE if fortran else pickle.NEWFALSE, data) + \
        pickle.BUILD


def refused(data: bytes, *words: str) -> str:
    """The message of the DatasetError ``data`` is refused with; it names the file and every word."""
    with pytest.raises(DatasetError) as e:
        load_pickle(data, "gt/evil.pkl")
    msg = str(e.value)
    assert "gt/evil.pkl" in msg and "\n" not in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


# ----------------------------------------------------------------------------------------------- plain data

keys = st.none() | st.booleans() | st.integers(-2**63, 2**63 - 1) | st.floats(allow_nan=False) | \
    st.text(max_size=6) | st.binary(max_size=6) | st.tuples(st.integers(-5, 5), st.text(max_size=3))
leaves = keys | st.binary(max_size=6).map(bytearray) | \
    st.builds(range, st.integers(-50, 50), st.integers(-50, 50), st.integers(1, 7))
plain = st.recursive(leaves, lambda c: st.lists(c, max_size=4) | st.lists(c, max_size=3).map(tuple)
                     | st.dictionaries(keys, c, max_size=3) | st.sets(keys, max_size=3)
                     | st.frozensets(keys, max_size=3), max_leaves=16)


@FAST
@given(plain, st.integers(0, 5))
def test_plain_data_reads_as_pickle_loads_does(obj, protocol):
    ours, theirs = roundtrip(obj, protocol)
    assert same(ours, theirs)


def test_python2_pickles_with_byte_strings():
    # Python 2, protocol 0: a numpy array whose bytes are an escaped STRING (pickletools' genops refuses it)
    p0 = (b"cnumpy.core.multiarray\n_reconstruct\np0\n(cnumpy\nndarray\np1\n(I0\ntp2\nS'b'\np3\ntp4\nRp5\n"
          b"(I1\n(I2\ntp6\ncnumpy\ndtype\np7\n(S'f8'\np8\nI0\nI1\ntp9\nRp10\n(I3\nS'<'\np11\nNNNI-1\nI-1\nI0\n"
          b"tp12\nbI00\nS'\\x00\\x00\\x00\\x00\\x00\\x00\\xf0?\\x00\\x00\\x00\\x00\\x00\\x00\\x00@'\np13\ntp14\nb.")
    out = load_pickle(p0, "py2.pkl")
    assert same(out, np.array([1.0, 2.0]))
    # Python 2, protocol 2: SHORT_BINSTRING data, __builtin__ set and xrange, a byte string as latin-1 text
    p2 = (b"\x80\x02]q\x00(cnumpy.core.multiarray\n_reconstruct\nq\x01cnumpy\nndarray\nq\x02K\x00\x85U\x01b\x87R"
          b"(K\x01K\x02\x85cnumpy\ndtype\nq\x03U\x02i8K\x00K\x01\x87R(K\x03U\x01<NNNJ\xff\xff\xff\xffJ\xff\xff\xff"
          b"\xffK\x00tb\x89U\x10" + np.array([7, 9], "<i8").tobytes() + b"tbc__builtin__\nset\n]q\x04(K\x01K\x02e"
          b"\x85Rc__builtin__\nxrange\nK\x00K\x03K\x01\x87RU\x03ab\xffI01\nL12L\ne.")
    out = load_pickle(p2, "py2.pkl")
    assert same(out[0], np.array([7, 9], dtype=np.int64))
    assert out[1:] == [{1, 2}, range(3), "ab\xff", True, 12] and type(out[4]) is bool


# ----------------------------------------------------------------------------------------------- numpy


def arrays_of(code: str, rng: np.random.Generator):
    """Arrays of one dtype in both byte orders: C, Fortran, transposed, strided, 0-d and empty."""
    for order in "<>":
        dt = np.dtype(code) if np.dtype(code).itemsize == 1 else np.dtype(code).newbyteorder(order)
        base = (rng.random(24) > 0.5) if code == "b1" else (rng.random(24) * 100 - (code[0] != "u") * 50)
        base = base.astype(dt)
        yield from (base.reshape(2, 3, 4), np.asfortranarray(base.reshape(4, 6)), base[::3], np.array(base[5]),
                    base.reshape(2, 3, 4).transpose(1, 0, 2), base[:0].reshape(0, 3),
                    np.asfortranarray(base.reshape(4, 6))[:, ::2])


@pytest.mark.parametrize("code", DTYPES)
def test_numpy_arrays_of_every_allowed_dtype(code, rng):
    for arr in arrays_of(code, rng):
        for protocol in range(6):
            ours, theirs = roundtrip(arr, protocol)
            assert same(ours, theirs), (arr.dtype, arr.shape, protocol)
            assert ours.flags.writeable and ours.flags.owndata


@pytest.mark.parametrize("code", DTYPES)
def test_numpy_scalars(code):
    for value in (0, 1, 3):
        scalar = np.dtype(code).type(value)
        for protocol in range(6):
            ours, theirs = roundtrip(scalar, protocol)
            assert same(ours, theirs)


def objects(shape: tuple[int, ...], items: list) -> np.ndarray:
    """An object array of ``shape`` holding ``items`` as they are (numpy does not unpack them)."""
    out = np.empty(shape, dtype=object)
    for i, item in zip(np.ndindex(shape), items, strict=True):
        out[i] = item
    return out


def object_arrays() -> list[np.ndarray]:
    ragged = objects((3,), [np.arange(3), np.zeros(0, np.int32), np.array([[1.5, 2.5]], dtype=">f4")])
    nested = objects((2,), [ragged, np.array(["a", None, 3], dtype=object)])
    grid = objects((2, 3), [1, "two", None, [3], (4,), {5: b"6"}])
    zero_d = objects((), [[1, 2]])
    return [ragged, nested, grid, np.asfortranarray(grid), zero_d, np.empty((0, 2), dtype=object),
            np.array([np.int64(4), np.float32(0.5), True], dtype=object)]


@pytest.mark.parametrize("protocol", range(6))
def test_object_arrays(protocol):
    for arr in object_arrays():
        ours, theirs = roundtrip(arr, protocol)
        assert same(ours, theirs)


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_npy_files_of_objects(tmp_path, protocol):
    for i, arr in enumerate(object_arrays()):
        path = tmp_path / f"a{i}.npy"
        path.write_bytes(npy_bytes(arr, protocol))
        assert same(load_npy_objects(path), np.load(path, allow_pickle=True))


def vpr_bench_ground_truth(n: int, as_lists: bool, rng: np.random.Generator) -> np.ndarray:
    """VPR-Bench's ``ground_truth_new.npy``: rows ``[query_index, reference_indices]``."""
    gt = np.empty((n, 2), dtype=object)
    for q in range(n):
        refs = np.unique(rng.integers(0, 5 * n, size=int(rng.integers(0, 4))))
        gt[q, 0], gt[q, 1] = q, (refs.tolist() if as_lists else refs)
    return gt


@pytest.mark.parametrize("as_lists", [False, True])
def test_vpr_bench_ground_truth(tmp_path, as_lists, rng):
    gt = vpr_bench_ground_truth(50, as_lists, rng)
    path = tmp_path / "ground_truth_new.npy"
    np.save(path, gt, allow_pickle=True)
    out = load_npy_objects(path)
    assert same(out, np.load(path, allow_pickle=True)) and out.shape == (50, 2)


def test_plain_pickle_of_lists_and_ranges(tmp_path):
    gt = [[q, range(max(0, q - 2), q + 3)] for q in range(20)] + [[20, []], [21, [4, 9]]]
    for name in ("gt.pkl", "gt.pickle", "gt.npy"):
        path = tmp_path / name
        path.write_bytes(pickle.dumps(gt, protocol=2))
        assert load_npy_objects(path) == gt


def test_a_large_object_array_loads_in_linear_time(tmp_path, rng):
    gt = vpr_bench_ground_truth(5_000, False, rng)
    path = tmp_path / "big.npy"
    np.save(path, gt, allow_pickle=True)
    start = time.perf_counter()
    out = load_npy_objects(path)
    assert time.perf_counter() - start < 10
    assert out.shape == (5_000, 2) and all(np.array_equal(a, b) for a, b in zip(out[:, 1], gt[:, 1], strict=True))


def test_hand_built_streams_are_read():
    """The builders of the refusal tests make valid streams (so a refusal is the check, not a typo)."""
    assert same(load_pickle(stream(array((2,), dtype("i8"), raw(np.arange(2).tobytes()))), "x"), np.arange(2))
    big_endian = raw(np.arange(4, dtype=">f4").tobytes())
    out = load_pickle(stream(array((2, 2), dtype("f4", dstate(">")), big_endian, fortran=True)), "x")
    assert same(out, np.asfortranarray(np.arange(4.0, dtype="f4").reshape(2, 2).T))  # native, as numpy makes it
    assert load_pickle(stream(array((1,), dtype("b1"), raw(b"\x02"))), "x").view(np.uint8)[0] == 1  # a bool is 0/1
    made = glob("numpy.core.multiarray", "_reconstruct") + tup(glob("numpy", "ndarray"), tup(num(0)), raw(b"b")) + \
        pickle.REDUCE
    state = tup(num(1), tup(num(2)), dtype("i8"), pickle.NEWFALSE, raw(bytes(16))) + pickle.BUILD
    twice = load_pickle(stream(pickle.MARK, made, pickle.DUP, state, pickle.TUPLE), "x")  # the copy below is built too
    assert twice[0] is twice[1] and same(twice[0], np.zeros(2, np.int64))
    memo = load_pickle(stream(made, pickle.BINPUT + b"\x07", state, pickle.POP, pickle.BINGET + b"\x07"), "x")
    assert same(memo, np.zeros(2, np.int64))  # the memo gives the built array, not its holder


# ----------------------------------------------------------------------------------------------- refusals


class RunsACommand:
    def __reduce__(self):
        return os.system, ("echo pwned",)


class Plain:
    pass


def test_os_system_is_refused_and_nothing_is_imported():
    refused(b"cos\nsystem\n(S'echo pwned'\ntR.", "refusing os.system", "only plain data and NumPy arrays are read")
    refused(b"\x80\x04\x8c\x02os\x8c\x06system\x93\x8c\x04true\x85R.", "refusing os.system")
    before = set(sys.modules)
    refused(stream(glob("seqnet_canary_module", "boom")), "seqnet_canary_module.boom")
    refused(stream(glob("numpy", "load")), "refusing numpy.load")
    assert set(sys.modules) == before


@pytest.mark.parametrize("protocol", range(6))
def test_reduce_of_a_user_class_is_refused(protocol):
    refused(pickle.dumps(RunsACommand(), protocol), "system")
    refused(pickle.dumps(Plain(), protocol))
    refused(pickle.dumps([1, Plain], protocol), "Plain")


def test_names_never_become_values():
    refused(stream(glob("builtins", "range")), "the name builtins.range is used as a value")
    refused(stream(pickle.EMPTY_LIST, glob("numpy", "dtype"), pickle.APPEND), "used as a value")
    refused(stream(glob("numpy", "ndarray"), tup(num(1)), pickle.REDUCE), "refusing to call")
    refused(stream(glob("numpy", "dtype"), tup(text("i8")), pickle.REDUCE), "before its state is set")
    refused(stream(pickle.EMPTY_LIST, glob("numpy", "dtype"), tup(text("i8")), pickle.REDUCE, pickle.APPEND),
            "before its state is set")
    refused(stream(glob("builtins", "set"), tup(glob("numpy", "ndarray")), pickle.REDUCE))


@pytest.mark.parametrize("code", ["V8", "S5", "U3", "M8", "m8[s]", "c16", "f16", "i3", "O", "|O8"])
def test_dtypes_other_than_plain_numbers_are_refused(code):
    refused(stream(dtype(code, dstate("|"))), "refusing", "dtype")


def test_crafted_dtype_states_are_refused():
    fields = pickle.EMPTY_DICT + text("a") + tup(dtype("i8"), num(0)) + pickle.SETITEM
    refused(stream(dtype("i8", dstate(names=tup(text("a")), fields=fields))), "sub-arrays or fields")
    refused(stream(dtype("O8", dstate("|", sub=tup(dtype("i8"), tup(num(2)))))), "sub-arrays or fields")
    refused(stream(dtype("i8", dstate(version=9))), "unknown state")
    refused(stream(dtype("i8", dstate("?"))), "unknown state")
    refused(stream(dtype("i8", tup(num(3)))), "unknown state")
    refused(stream(dtype("i8", dstate()), dstate(), pickle.BUILD), "refusing to set the state")  # a built dtype


def test_objects_are_never_made_from_bytes():
    pointer = raw(struct.pack("<Q", 0x4141414141414141))
    scalar = glob("numpy.core.multiarray", "scalar")
    refused(stream(scalar, tup(dtype("O8"), pointer), pickle.REDUCE), "refusing")
    refused(stream(array((1,), dtype("O8"), pointer)), "object array")
    refused(stream(glob("numpy._core.numeric", "_frombuffer"), tup(pointer, dtype("O8"), tup(num(1)), text("C")),
                   pickle.REDUCE), "numeric dtype")


def test_sizes_are_checked_before_anything_is_allocated():
    refused(pickle.dumps(range(10**12), 2), "range", "elements")
    refused(pickle.dumps(range(-2**63, 2**63 - 1, 1), 4), "elements")
    refused(stream(array((10**6, 10**6), dtype("f8"), raw(b""))), "elements")
    refused(stream(array((3,), dtype("f8"), raw(b"\0" * 8))), "need 24 bytes", "has 8")
    refused(stream(array((2, -1), dtype("f8"), raw(b"\0" * 8))), "shape")
    refused(stream(array((1,) * 65, dtype("f8"), raw(b"\0" * 8))), "shape")
    refused(stream(glob("numpy._core.numeric", "_frombuffer"), tup(pickle.BYTEARRAY8 + struct.pack("<Q", 8) + b"\0" * 8,
                   dtype("f8"), tup(num(10**9), num(10**9)), text("C")), pickle.REDUCE), "elements")
    refused(stream(glob("builtins", "bytearray"), tup(num(10**12)), pickle.REDUCE), "refusing")
    refused(stream(glob("builtins", "range"), tup(num(1), num(2), num(0)), pickle.REDUCE), "refusing")
    refused(stream(glob("_codecs", "encode"), tup(text("x" * 9), text("utf-16")), pickle.REDUCE), "refusing")
    assert load_pickle(pickle.dumps(range(10**6), 2), "x") == range(10**6)


@pytest.mark.parametrize("protocol", range(6))
def test_integers_past_2_63_are_refused(protocol):
    refused(pickle.dumps(2**63, protocol), "too large to be an index")
    refused(pickle.dumps([1, -2**63 - 1], protocol), "too large to be an index")
    refused(pickle.dumps(10**1000, protocol), "too large to be an index")
    assert load_pickle(pickle.dumps([2**63 - 1, -2**63], protocol), "x") == [2**63 - 1, -2**63]


def test_unhashable_keys_are_refused():
    refused(stream(pickle.EMPTY_DICT, pickle.EMPTY_LIST, num(1), pickle.SETITEM), "dict key or set member is list")
    refused(stream(pickle.EMPTY_SET, pickle.MARK, pickle.EMPTY_DICT, pickle.ADDITEMS), "is dict")
    refused(stream(pickle.MARK, pickle.EMPTY_LIST, pickle.FROZENSET), "is list")
    refused(stream(pickle.EMPTY_DICT, array((1,), dtype("i8"), raw(b"\0" * 8)), num(1), pickle.SETITEM), "ndarray")
    refused(stream(pickle.EMPTY_DICT, tup(num(1), pickle.EMPTY_LIST), num(1), pickle.SETITEM), "is list")
    deep = pickle.MARK * 100 + pickle.TUPLE * 100
    refused(stream(pickle.EMPTY_DICT, deep, num(1), pickle.SETITEM), "over 64 items")
    refused(stream(glob("builtins", "set"), tup(pickle.EMPTY_LIST + pickle.EMPTY_LIST + pickle.APPEND), pickle.REDUCE))
    assert load_pickle(stream(pickle.EMPTY_DICT, tup(num(1), text("a")), num(1), pickle.SETITEM), "x") == {(1, "a"): 1}


@pytest.mark.parametrize("data, words", [
    (b"\x80\x02h\x05.", "memo index 5"), (b"\x80\x02a.", "too few items"), (b"\x80\x02t.", "MARK"),
    (b"\x80\x02\x85.", "too few items"), (b"\x80\x02K\x01", "STOP"), (b"", "STOP"), (b"\x80\x02K\x01K\x02a.", "list"),
    (b"\x80\x02]K\x01K\x02s.", "dict"), (b"\x80\x02]}b.", "state"), (b"\x80\x02(K\x01d.", "odd number"),
    (b"\x80\x02\xff.", "not an opcode"), (b"\x80\x09N.", "protocol 9"), (b"\x80\x02X\xff\xff\xff\x7f.", "malformed"),
    (b"(i__main__\nX\n.", "INST"), (b"Pabc\n.", "PERSID"),
    (b"\x80\x02N\x81.", "NEWOBJ"), (b"\x80\x02\x82\x01.", "EXT1"), (b"\x80\x05\x97.", "NEXT_BUFFER"),
    (b"\x80\x05N\x98.", "READONLY_BUFFER"), (b"\x80\x02NQ.", "BINPERSID"), (b"\x80\x02(No.", "OBJ"),
])
def test_malformed_streams_are_refused(data, words):
    refused(data, words)


def test_the_callers_error_class_is_used():
    with pytest.raises(ConfigError, match="refusing os.system"):
        load_pickle(b"cos\nsystem\n(S'x'\ntR.", "cfg.pkl", error=ConfigError)
    with pytest.raises(ConfigError, match="cfg.pkl"):
        load_pickle(b"\x80\x02X\x05\x00\x00\x00ab", "cfg.pkl", error=ConfigError)


def test_deep_nesting_needs_no_recursion():
    n = 20_000
    out = load_pickle(b"\x80\x02" + b"]" * n + b"a" * (n - 1) + b".", "deep.pkl")
    depth = 0
    while out:
        out, depth = out[0], depth + 1
    assert depth == n - 1
    assert load_pickle(b"(" * n + b"t" * n + b".", "deep.pkl") is not None


# ----------------------------------------------------------------------------------------------- robustness

SEEDS = [pickle.dumps([1, (2.5, "é"), {b"k": None, 3: True}, {4, 5}, range(3)], p) for p in range(6)] + \
    [pickle.dumps(a, p) for a in (np.arange(6.0).reshape(2, 3), object_arrays()[0]) for p in (0, 2, 5)] + \
    [pickle.dumps(vpr_bench_ground_truth(3, False, np.random.default_rng(1)), 4)]


def load_or_refuse(data: bytes) -> None:
    start = time.perf_counter()
    try:
        load_pickle(data, "fuzz.pkl")
    except DatasetError:
        pass
    assert time.perf_counter() - start < 2


def test_every_prefix_gives_a_value_or_the_error():
    for data in SEEDS:
        load_pickle(data, "x")
        for k in range(len(data)):
            load_or_refuse(data[:k])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(SEEDS), st.lists(st.tuples(st.sampled_from("fid"), st.floats(0, 1), st.integers(0, 255)),
                                        min_size=1, max_size=6))
def test_mutated_streams_give_a_value_or_the_error(data, edits):
    data = bytearray(data)
    for kind, where, byte in edits:
        i = min(int(where * len(data)), len(data) - 1)
        if kind == "f":
            data[i] ^= byte or 1
        elif kind == "i":
            data.insert(i, byte)
        elif len(data) > 1:
            del data[i]
    load_or_refuse(bytes(data))


# ----------------------------------------------------------------------------------------------- files


def test_npy_files(tmp_path, monkeypatch):
    numeric = tmp_path / "numbers.npy"
    np.save(numeric, np.arange(3))
    with pytest.raises(DatasetError, match="numbers.npy .*not of objects"):
        load_npy_objects(numeric)
    liar = tmp_path / "liar.npy"
    arr = object_arrays()[0]
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "|O", "fortran_order": False, "shape": (7,)})
    liar.write_bytes(head.getvalue() + pickle.dumps(arr, 4))
    with pytest.raises(DatasetError, match=r"liar.npy: its .npy header declares shape \(7,\)"):
        load_npy_objects(liar)
    evil = tmp_path / "evil.npy"
    evil.write_bytes(head.getvalue() + b"cos\nsystem\n(S'echo pwned'\ntR.")
    with pytest.raises(DatasetError, match="evil.npy as a pickle: refusing os.system"):
        load_npy_objects(evil)
    empty = tmp_path / "empty.pkl"
    empty.write_bytes(b"")
    with pytest.raises(DatasetError, match="empty.pkl: it is empty"):
        load_npy_objects(empty)
    with pytest.raises(DatasetError, match="not found"):
        load_npy_objects(tmp_path / "missing.npy")
    fifo = tmp_path / "pipe.npy"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match="FIFO"):
        load_npy_objects(fifo)
    big = tmp_path / "big.pkl"
    big.write_bytes(pickle.dumps(list(range(100)), 2))
    monkeypatch.setattr(unpickle, "MAX_FILE_BYTES", 100)
    with pytest.raises(DatasetError, match="big.pkl: it has .* bytes, more than the 100"):
        load_npy_objects(big, error=DatasetError)
    with pytest.raises(ConfigError, match="named-by-caller"):
        load_npy_objects(empty, where="named-by-caller", error=ConfigError)


def test_the_budget_is_16_elements_a_byte_plus_a_million():
    def ranged(n: int) -> bytes:
        return stream(glob("builtins", "range"), tup(num(n)), pickle.REDUCE)

    budget = 16 * len(ranged(10**6)) + 10**6  # the same length for every 7-digit n
    assert load_pickle(ranged(budget), "x") == range(budget)
    refused(ranged(budget + 1), "elements")
    shape = (budget // 1000, 1000)
    assert math.prod(shape) <= budget
    assert load_pickle(stream(array(shape, dtype("u1"), raw(bytes(math.prod(shape))))), "x").shape == shape
