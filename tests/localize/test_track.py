"""A video query's sampling and track, settled before any frame: the map's sampling taken or warned, a track that
places nothing (milliseconds, a gap, lat/lon swapped) refused, and a clock offset said after the run."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.localize.track import Sampling, check_near_route, map_sampling, resolve_sampling


@pytest.mark.parametrize(("meta", "want"), [
    ({}, None), ({"sampling": "5"}, None), ({"sampling": {"fps": "5"}}, None), ({"sampling": {"fps": True}}, None),
    ({"sampling": {"fps": -1}}, None),
    ({"sampling": {"fps": 5.0, "every_metres": None}}, Sampling(5.0, None, "map")),
    ({"sampling": {"fps": 5.0, "every_metres": 20}}, Sampling(None, 20, "map")),  # from-video: metres win
    ({"sampling": {"fps": None, "every_metres": None}}, Sampling(None, None, "map")),
])
def test_map_sampling_reads_only_positive_numbers(meta, want):
    assert map_sampling(meta) == want


def test_the_map_sampling_is_taken_unless_the_user_says_otherwise(caplog):
    fps5, m20 = Sampling(5.0, None, "map"), Sampling(None, 20.0, "map")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert resolve_sampling(None, None, fps5, False) == fps5
        assert resolve_sampling(None, None, m20, True) == m20
        assert resolve_sampling(None, None, None, True) == Sampling()
        assert resolve_sampling(5.0, None, fps5, False) == Sampling(5.0, None, "options")
    assert not caplog.records  # as the map: nothing to say
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert resolve_sampling(10.0, None, fps5, False) == Sampling(10.0, None, "options")
    assert "the map keeps 5 frames/s of its video, this query 10 frames/s" in caplog.text and "--fps 5" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert resolve_sampling(None, None, m20, False) == Sampling()  # no track: every frame, said
    assert "one frame per 20 m" in caplog.text and "--positions FILE" in caplog.text


@pytest.mark.parametrize(("fps", "metres", "positions", "text"), [
    (5.0, 20.0, True, "give one of --fps and --every-metres"),
    (None, 20.0, False, "--every-metres needs the query's track"),
])
def test_conflicting_sampling_options_are_refused(fps, metres, positions, text):
    with pytest.raises(ConfigError, match=text):
        resolve_sampling(fps, metres, None, positions)


def test_a_track_far_from_the_route_is_refused_with_a_hint():
    r = np.stack([np.arange(50) * 10.0, np.zeros(50)], axis=1)
    check_near_route(r[:5] + [0, 20], r, 25.0, "the track t.csv", True)  # 20 m off the route: some within 25 m
    with pytest.raises(DatasetError, match=r"the nearest is 100 m away \(latitude and longitude swapped"):
        check_near_route(r[:5] + [0, 100], r, 25.0, "the track t.csv", True)
    with pytest.raises(DatasetError, match="another place"):
        check_near_route(r[:5] + [0, 100], r, 25.0, "the track t.csv", False)
