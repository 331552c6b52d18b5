"""seqnet.sources.times: the one ISO-8601 / UTC reading every source uses."""

from __future__ import annotations

import datetime

import pytest

from seqnet.sources.times import as_utc, parse_iso, utc_seconds

UTC = datetime.timezone.utc


@pytest.mark.parametrize("text, expected", [
    ("2024-05-01T10:00:00Z", datetime.datetime(2024, 5, 1, 10, tzinfo=UTC)),
    ("  2024-05-01T10:00:00  ", datetime.datetime(2024, 5, 1, 10, tzinfo=UTC)),  # no zone: UTC
    ("2024-05-01T12:00:00+02:00", datetime.datetime(2024, 5, 1, 10, tzinfo=UTC)),
    ("2024-05-01 10:00:00.5Z", datetime.datetime(2024, 5, 1, 10, 0, 0, 500000, tzinfo=UTC)),
])
def test_parse_iso_is_aware_and_utc_when_zoneless(text: str, expected: datetime.datetime) -> None:
    t = parse_iso(text)
    assert t.tzinfo is not None and t == expected


@pytest.mark.parametrize("text", ["", "yesterday", "2024-13-01T00:00:00", "12.5", "2024-05-01T25:00"])
def test_parse_iso_refuses_with_value_error(text: str) -> None:
    with pytest.raises(ValueError):
        parse_iso(text)


def test_utc_seconds_reads_a_zoneless_time_as_utc() -> None:
    naive = datetime.datetime(1970, 1, 2)
    assert utc_seconds(naive) == 86400.0
    assert utc_seconds(naive.replace(tzinfo=datetime.timezone(datetime.timedelta(hours=1)))) == 86400.0 - 3600
    aware = datetime.datetime(2020, 1, 1, tzinfo=datetime.timezone(datetime.timedelta(hours=-5)))
    assert as_utc(aware) is aware
