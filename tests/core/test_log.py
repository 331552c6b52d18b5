"""Message helpers of seqnet.core.log."""

from __future__ import annotations

from seqnet.core.log import counted, ordinal


def test_counted_and_ordinal():
    assert [counted(n, "image") for n in (0, 1, 2)] == ["0 images", "1 image", "2 images"]
    assert counted(1, "reference image") == "1 reference image" and counted(3, "query", "queries") == "3 queries"
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 21)] == ["1st", "2nd", "3rd", "4th", "11th", "21st"]
