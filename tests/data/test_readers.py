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
