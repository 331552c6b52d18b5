"""A MATLAB v5 ``.mat`` file checked against its own bytes before ``scipy.io.loadmat`` reads it.

``loadmat`` trusts the file: a compressed variable is inflated whole, an element declaring 4 GiB is
allocated before its bytes are found missing, a cell or struct declaring ``[2**31, 2**31]`` elements is
allocated first, and an element of an unknown type crashes its Cython reader (a segmentation fault).
Here (:func:`checked_mat`) the file is read whole (its size bounded), every compressed variable inflated
in blocks with the total bounded by :data:`~seqnet.security.arrays.MAX_RATIO` times the file's size (and
the memory there is), and every element walked: its type known, its bytes inside its parent, nesting
bounded, an array's class one of numbers, text, cells and structs, and its declared element count within
its bytes. Only the checked, uncompressed bytes reach ``loadmat``, and it reads them in a sandboxed child
(:mod:`.matlab`), so what it still does wrong ends that child, not this process.
"""

from __future__ import annotations

import math
import os
import struct
import zlib

from ..core.errors import DatasetError
from ..core.memory import available_bytes
from .arrays import MAX_RATIO
from .inputs import open_input

MAX_FILE = 1 << 30  # a struct file read whole
MAX_DEPTH = 32  # nested cells / structs
HEADER = 128
MI_INT8, MI_UINT8, MI_INT32, MI_UINT32, MI_MATRIX, MI_COMPRESSED = 1, 2, 5, 6, 14, 15
ITEM_SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8}  # numeric element types
UTF_BYTES = {16: (1, 4), 17: (2, 4), 18: (4, 4)}  # bytes per character of miUTF8 / 16 / 32
CHAR_TYPES = {1, 2, 3, 4, 5, 6}  # integer types scipy also reads characters from
COMPLEX = 0x800
MI_TYPES = {1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 16, 17, 18}  # the element types scipy reads (15: top level only)
CELL, STRUCT, CHAR = 1, 2, 4
CLASSES = {CELL, STRUCT, CHAR, *range(6, 16)}  # cell, struct, char, double .. uint64 (no objects, sparse, functions)
BLOCK = 1 << 20


def checked_mat(path: str | os.PathLike[str], what: str = "struct file") -> bytes:
    """The bytes of a MATLAB v5 file, uncompressed, after the checks of the module docstring."""
    with open_input(path, what) as f:
        size = os.fstat(f.fileno()).st_size
        if size > MAX_FILE:
            raise DatasetError(f"{what} {path} has {size} bytes, more than the {MAX_FILE} a .mat struct file may have")
        data = f.read(MAX_FILE + 1)
    return MatChecker(data, str(path)).checked()


class MatChecker:
    """The walk over one file's elements (:meth:`checked`)."""

    def __init__(self, data: bytes, where: str) -> None:
        self.data, self.where = data, where
        avail = available_bytes()
        self.budget = min(len(data) * MAX_RATIO + BLOCK, max(BLOCK, avail // 4) if avail else 1 << 34)
        self.order = "<"

    def fail(self, why: str) -> DatasetError:
        return DatasetError(f"cannot read {self.where} as a MATLAB v5 .mat file: {why}; hint: pass a seqNet "
                            "structFiles/*.db")

    def checked(self) -> bytes:
        """The file's bytes with every compressed variable inflated, after every element was checked."""
        data = self.data
        if len(data) < HEADER or 0 in data[:4]:
            raise self.fail("it has no MATLAB 5.0 header (MATLAB v4 files and other formats are not read)")
        endian, version = data[126:128], data[124:126]
        if endian not in (b"IM", b"MI"):
            raise self.fail(f"its header's endian mark is {endian!r}, not 'IM' or 'MI'")
        self.order = "<" if endian == b"IM" else ">"
        if struct.unpack(self.order + "H", version)[0] != 0x0100:
            raise self.fail("it is not version 5 (a v7.3 file is HDF5: save it with -v7)")
        out, pos = [data[:HEADER]], HEADER
        while pos + 8 <= len(data):
            mdtype, n, body = self.tag(data, pos, len(data))
            element = data[pos:body + n]
            if mdtype == MI_COMPRESSED:
                element = self.inflate(data[body:body + n])
            self.variable(element)
            out.append(element)
            pos = body + n
        return b"".join(out)

    def tag(self, buf: bytes, pos: int, end: int) -> tuple[int, int, int]:
        """``(mdtype, byte count, where the data starts)`` of the element tag at ``pos``, which must fit before
        ``end`` (a small element's 4 data bytes are inside its 8-byte tag)."""
        if pos + 8 > end:
            raise self.fail(f"an element tag at byte {pos} runs past its end ({end})")
        word, count = struct.unpack_from(self.order + "II", buf, pos)
        mdtype = word & 0xFFFF if word >> 16 else word
        if mdtype not in MI_TYPES and mdtype != MI_COMPRESSED:
            raise self.fail(f"the element at byte {pos} is of unknown type {mdtype}")
        if word >> 16:
            if word >> 16 > 4:
                raise self.fail(f"the small element at byte {pos} declares {word >> 16} bytes (at most 4)")
            return mdtype, word >> 16, pos + 4
        if count > end - pos - 8:
            raise self.fail(f"an element at byte {pos} declares {count} bytes, but only {end - pos - 8} follow")
        return word, count, pos + 8

    def inflate(self, compressed: bytes) -> bytes:
        """A compressed variable's bytes, inflated block by block within the budget of the whole file."""
        d, out, tail = zlib.decompressobj(), [], compressed
        try:
            while not d.eof:
                chunk = d.decompress(tail, BLOCK)
                tail = d.unconsumed_tail
                self.budget -= len(chunk)
                if self.budget < 0:
                    raise self.fail(f"its compressed variables inflate to more than {MAX_RATIO} times the file's "
                                    "size (a decompression bomb)")
                if not chunk and not tail:
                    raise self.fail("a compressed variable ends early")
                out.append(chunk)
        except zlib.error as e:
            raise self.fail(f"a compressed variable is damaged ({e})") from e
        return b"".join(out)

    def variable(self, element: bytes) -> None:
        """One top-level element (inflated when it was compressed): a ``miMATRIX``, checked."""
        mdtype, n, body = self.tag(element, 0, len(element))
        if mdtype != MI_MATRIX:
            raise self.fail(f"a top-level element is of type {mdtype}, not a variable (miMATRIX)")
        self.matrix(element, body, body + n, 0)

    def subelements(self, buf: bytes, pos: int, end: int) -> list[tuple[int, int, int]]:
        """``(mdtype, byte count, data start)`` of the elements that tile ``buf[pos:end]`` (each padded to 8)."""
        out = []
        while pos + 8 <= end:
            mdtype, n, body = self.tag(buf, pos, end)
            out.append((mdtype, n, body))
            pos = pos + 8 if body == pos + 4 else body + n + (-n % 8)
        return out

    def matrix(self, buf: bytes, pos: int, end: int, depth: int) -> None:
        """A ``miMATRIX`` body: flags, dimensions and name, then exactly the parts its class and dimensions
        call for (one data element, or one array per cell / per field of each struct element), checked."""
        if depth > MAX_DEPTH:
            raise self.fail(f"its cells or structs nest deeper than {MAX_DEPTH} levels")
        parts = self.subelements(buf, pos, end)
        if not parts:
            return  # an empty cell entry
        if len(parts) < 3 or parts[0][:2] != (MI_UINT32, 8) or parts[1][0] != MI_INT32 or parts[1][1] % 4 or \
                parts[1][1] < 8 or parts[2][0] not in (MI_INT8, MI_UINT8):
            raise self.fail(f"the array at byte {pos} lacks its flags, dimensions or name")
        flags = struct.unpack_from(self.order + "I", buf, parts[0][2])[0]
        cls = flags & 0xFF
        if cls not in CLASSES or flags & COMPLEX:
            raise self.fail(f"the array at byte {pos} is of MATLAB class {cls}{' (complex)' * bool(flags & COMPLEX)}, "
                            "not numbers, text, a cell or a struct")
        dims = struct.unpack_from(f"{self.order}{parts[1][1] // 4}i", buf, parts[1][2])
        count = math.prod(dims) if all(d >= 0 for d in dims) else -1
        fields = self.fields(buf, parts, pos) if cls == STRUCT else 1
        per = 8 * max(fields, 1) if cls in (CELL, STRUCT) else 1
        if count < 0 or count * per > end - pos:
            raise self.fail(f"the array at byte {pos} declares dimensions {list(dims)[:8]}, more elements than its "
                            f"{end - pos} bytes hold")
        head = 5 if cls == STRUCT else 3
        want = head + count * fields if cls in (CELL, STRUCT) else 4
        if len(parts) != want:
            raise self.fail(f"the array at byte {pos} (class {cls}, dimensions {list(dims)[:8]}) has {len(parts)} "
                            f"parts, not {want}")
        if cls not in (CELL, STRUCT):
            self.values(parts[3], cls, count, pos)
        for mdtype, n, body in parts[head:] if cls in (CELL, STRUCT) else ():
            if mdtype != MI_MATRIX:
                raise self.fail(f"an element of the array at byte {pos} is of type {mdtype}, not an array")
            self.matrix(buf, body, body + n, depth + 1)

    def fields(self, buf: bytes, parts: list[tuple[int, int, int]], pos: int) -> int:
        """The number of fields of a struct: its field names' width (a small int32) and their bytes."""
        if len(parts) < 5 or parts[3][:2] != (MI_INT32, 4) or parts[4][0] not in (MI_INT8, MI_UINT8):
            raise self.fail(f"the struct at byte {pos} lacks its field names")
        width = struct.unpack_from(self.order + "i", buf, parts[3][2])[0]
        if width <= 0 or parts[4][1] % width:
            raise self.fail(f"the struct at byte {pos} has field names of width {width} in {parts[4][1]} bytes")
        return parts[4][1] // width

    def values(self, part: tuple[int, int, int], cls: int, count: int, pos: int) -> None:
        """The data element of a numeric or char array holds exactly ``count`` values of a type of its class."""
        mdtype, n, _ = part
        if cls == CHAR and mdtype in UTF_BYTES:
            ok = count * UTF_BYTES[mdtype][0] <= n <= count * UTF_BYTES[mdtype][1]
        else:
            ok = mdtype in ITEM_SIZES and (cls != CHAR or mdtype in CHAR_TYPES) and n == count * ITEM_SIZES[mdtype]
        if not ok:
            raise self.fail(f"the array at byte {pos} (class {cls}) holds {n} bytes of type {mdtype} for {count} "
                            "values")
