"""Message helpers of seqnet.core.log."""

from __future__ import annotations

from seqnet.core.log import counted, ordinal


def test_counted_and_ordinal():
    assert [counted(n, "image") for n in (0, 1, 2)] == ["0 images", "1 image", "2 images"]
    assert counted(1, "reference image") == "1 reference image" and counted(3, "query", "queries") == "3 queries"
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 21)] == ["1st", "2nd", "3rd", "4th", "11th", "21st"]


def test_warn_once_says_each_key_once(caplog):
    from seqnet.core.log import warn_once

    with caplog.at_level("WARNING", logger="seqnet"):
        for _ in range(3):
            warn_once(("test", "a"), "file %s changed", "a")
        warn_once(("test", "b"), "file %s changed", "b")
    assert [r.getMessage() for r in caplog.records] == ["file a changed", "file b changed"]
