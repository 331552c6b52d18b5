"""Every reader of files from strangers under mutated files (benchmarks/fuzz_readers.py, seconds per reader in
CI; an hour per reader with ``--seconds 3600`` nightly): a value or a seqnet error, never another exception, a
crash, a hang or an allocation beyond the bound."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "fuzz_readers.py"
CASES = {"arrays": 60, "dataset": 40, "torch": 40, "positives": 40, "text": 40, "map": 30, "foreign": 30, "bags": 20,
         "hdf5": 12, "faiss": 12}  # the last two start a sandboxed child per case


@pytest.mark.parametrize("reader", list(CASES))
def test_reader_survives_mutated_files(reader, tmp_path):
    summary = tmp_path / "summary.json"
    p = subprocess.run([sys.executable, str(SCRIPT), "--reader", reader, "--cases", str(CASES[reader]), "--seed",
                        "7", "--out", str(tmp_path / "findings"), "--json", str(summary)],
                       capture_output=True, text=True, timeout=600)
    assert summary.exists(), p.stderr[-2000:]
    (result,) = json.loads(summary.read_text())
    assert result["cases"] == CASES[reader]
    assert not result["findings"], result["findings"][:3]
    assert p.returncode == 0
