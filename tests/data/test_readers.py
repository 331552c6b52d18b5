"""Names files and text inputs read as untrusted files: non-blocking (a FIFO is refused), UTF-8, names without a
NUL or a line separator."""

from __future__ import annotations

import os

import pytest
from conftest import mutated, read_mutated
from hypothesis import HealthCheck, given, settings

from seqnet.core.errors import DatasetError
from seqnet.data.readers import read_names


def test_names_with_a_nul_or_from_a_fifo_are_refused(tmp_path):
    (tmp_path / "n.txt").write_bytes(b"a.png\nb\x00.png\n")
    with pytest.raises(DatasetError, match=r"name 1 'b\\x00.png' contains a NUL character"):
        read_names(tmp_path / "n.txt")
    os.mkfifo(tmp_path / "fifo.txt")
    with pytest.raises(DatasetError, match=r"names file .*fifo.txt is a FIFO \(named pipe\), not a regular file"):
        read_names(tmp_path / "fifo.txt")
    with pytest.raises(DatasetError, match=r"names file not found"):
        read_names(tmp_path / "none.txt")


@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=mutated(b"img/0001.png\nimg/0002.png\n  img/0003.png  \n\nimg/0004.png\n"))
def test_fuzzed_names_file_gives_names_or_one_error(tmp_path, data):
    names = read_mutated(read_names, tmp_path / "n.txt", data)
    assert names is None or len(set(names)) == len(names) and all(n and n == n.strip() and "\x00" not in n
                                                                  for n in names)


def test_descriptors_with_a_size_one_axis_are_read_as_n_by_d(tmp_path, caplog):
    """``[N, 1, D]`` (torch's unsqueeze, stacked ``[1, D]`` rows): read as ``[N, D]`` with a note; a 3-D array of
    three real axes is still refused; ``[N, D]`` says nothing."""
    import numpy as np

    from seqnet.data.readers import read_descriptor_file

    d = np.random.default_rng(0).standard_normal((20, 8)).astype(np.float32)
    np.save(tmp_path / "a.npy", d[:, None, :])
    with caplog.at_level("INFO", logger="seqnet"):
        got, _ = read_descriptor_file(tmp_path / "a.npy")
    assert got.shape == (20, 8) and np.array_equal(got, d)
    assert "a.npy: descriptors of shape (20, 1, 8) read as [N, D] (size-1 axes dropped)" in caplog.text
    np.save(tmp_path / "b.npy", d.reshape(20, 2, 4))
    with pytest.raises(DatasetError, match=r"must be a 2-D \[N, D\] array, got shape \(20, 2, 4\)"):
        read_descriptor_file(tmp_path / "b.npy")
    caplog.clear()
    np.save(tmp_path / "c.npy", d)
    with caplog.at_level("INFO", logger="seqnet"):
        assert read_descriptor_file(tmp_path / "c.npy")[0].shape == (20, 8)
    assert not caplog.records
