"""The one .npy writer: the bytes np.save writes, for every shape and dtype seqnet writes; blocks checked."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError
from seqnet.core.npy import row_blocks, write_npy, write_npy_rows


def npsave(x: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, x)
    return buf.getvalue()


def written(x: np.ndarray, block_bytes: int | None = None) -> bytes:
    buf = io.BytesIO()
    if block_bytes is None:
        write_npy(buf, x)
    else:
        write_npy_rows(buf, x.shape, x.dtype, row_blocks(x, block_bytes))
    return buf.getvalue()


@settings(max_examples=60, deadline=None)
@given(shape=st.lists(st.integers(0, 5), min_size=0, max_size=3),
       dtype=st.sampled_from(["<f4", "<f8", "<i8", "<f2", "|u1", "|b1", ">f4"]),
       block_bytes=st.sampled_from([None, 1, 7, 64]))
def test_bytes_equal_np_save(shape, dtype, block_bytes):
    x = (np.arange(int(np.prod(shape)), dtype=np.int64) % 7).astype(dtype).reshape(shape)
    if block_bytes is not None and x.ndim == 0:
        return
    assert written(x, block_bytes) == npsave(x)


def test_a_non_contiguous_view_is_written_in_c_order():
    x = np.arange(24, dtype=np.float32).reshape(4, 6)[:, ::2]
    assert written(x) == npsave(np.ascontiguousarray(x))


def test_blocks_that_do_not_add_up_are_refused():
    with pytest.raises(ConfigError, match="3 descriptor rows written of the 4 expected"):
        write_npy_rows(io.BytesIO(), (4, 2), "<f4", [np.zeros((3, 2))], "descriptor")
    with pytest.raises(ConfigError, match="does not fit rows 0"):
        write_npy_rows(io.BytesIO(), (4, 2), "<f4", [np.zeros((5, 2))])
    with pytest.raises(ConfigError, match="does not fit"):
        write_npy_rows(io.BytesIO(), (4, 2), "<f4", [np.zeros((4, 3))])


def test_object_arrays_are_never_written():
    with pytest.raises(ConfigError, match="pickle"):
        write_npy(io.BytesIO(), np.array([{"a": 1}], dtype=object))
