"""``--video-start`` of a two-video build: one time for both videos, or ``reference=ISO`` / ``query=ISO`` for one
(the hint for a query track two hours off said ``--video-start ...``, which set both videos' starts; followed, the
reference's track no longer overlapped its video)."""

from __future__ import annotations

import datetime

import pytest

from seqnet.core.errors import ConfigError
from seqnet.pipelines.from_video import FromVideoConfig, _starts

UTC = datetime.timezone.utc


def test_one_time_is_both_videos_and_a_side_sets_its_own():
    both = datetime.datetime(2024, 5, 1, 10, tzinfo=UTC)
    assert _starts(FromVideoConfig(video_start="2024-05-01T10:00:00Z")) == {"reference": both, "query": both}
    assert _starts(FromVideoConfig(video_start="query=2024-05-01T10:00:00Z")) == {"reference": None, "query": both}
    later = datetime.datetime(2024, 5, 1, 12, tzinfo=UTC)
    assert _starts(FromVideoConfig(video_start="reference=2024-05-01T10:00:00Z, query=2024-05-01T12:00:00Z")) == {
        "reference": both, "query": later}
    assert _starts(FromVideoConfig()) == {"reference": None, "query": None}


@pytest.mark.parametrize("text", ["query=2024-05-01T10:00:00Z,query=2024-05-01T11:00:00Z",
                                  "query=2024-05-01T10:00:00Z,2024-05-01T11:00:00Z", "query=yesterday"])
def test_a_malformed_start_is_one_line(text):
    with pytest.raises(ConfigError, match="--video-start"):
        _starts(FromVideoConfig(video_start=text))
