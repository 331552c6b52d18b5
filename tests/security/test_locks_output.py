"""A lock that cannot be made names the output it was for."""

from __future__ import annotations

import pytest

from seqnet.core.errors import OutputError
from seqnet.security.locks import locked


def test_a_lock_that_cannot_be_made_names_the_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(OutputError, match=r"cannot write .*file/out: its lock file \.out\.lock cannot be made in "):
        with locked(blocker / "out"):
            pass
