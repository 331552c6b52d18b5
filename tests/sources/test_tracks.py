"""GPX, NMEA 0183 and CSV tracks: one :class:`Track` each, the same samples from each format; their refusals."""

from __future__ import annotations

import datetime
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import mutated, read_mutated, route, write_gpx, write_nmea, write_track_csv
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.sources.tracks import read_track
from seqnet.sources.tracks.clock import in_milliseconds, parse_start, video_times, why_outside
from seqnet.sources.tracks.metres import to_metres

T0 = datetime.datetime(2024, 5, 1, 10, 0, 0, tzinfo=datetime.timezone.utc)


def _samples(n: int = 30):
    times = np.cumsum(np.r_[0.0, np.full(n - 1, 0.5)])
    return (times, *route(n))


def test_three_formats_give_one_track(tmp_path):
    times, lat, lon = _samples()
    gpx = read_track(write_gpx(tmp_path / "a.gpx", T0, times, lat, lon))
    nmea = read_track(write_nmea(tmp_path / "a.nmea", T0, times, lat, lon))
    iso = read_track(write_track_csv(tmp_path / "a.csv", times, lat, lon, t0=T0))
    rel = read_track(write_track_csv(tmp_path / "r.csv", times, lat, lon))
    for t in (gpx, nmea, iso):
        assert t.absolute and t.geographic and t.dated
        np.testing.assert_allclose(t.times, T0.timestamp() + times, atol=0.006)  # NMEA: hundredths of a second
        np.testing.assert_allclose(t.coords, np.stack([lat, lon], 1), atol=1e-6)  # NMEA: 1e-6 minutes
    assert not rel.absolute and rel.times[0] == 0.0
    xy, frame = to_metres(gpx)
    assert frame == "UTM zone 33W"
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    np.testing.assert_allclose(steps, 10.0, rtol=0.01)  # the route's 10 m spacing, in metres again


def test_nmea_without_dates_and_bad_lines(tmp_path):
    times, lat, lon = _samples(10)
    p = write_nmea(tmp_path / "gga.nmea", T0, times, lat, lon, gga_only=True)
    text = p.read_text().splitlines()
    text[3] = text[3][:-2] + "00"  # a wrong checksum: left out
    p.write_text("\n".join(["$GPGSV,3,1,11,03,03,111,00*74", *text, "garbage"]) + "\n")
    t = read_track(p)
    assert not t.dated and len(t.times) == 9
    np.testing.assert_allclose(t.times[:2], [36000.0, 36000.5])  # seconds of the day
    rel = video_times(t, T0, 60.0)
    np.testing.assert_allclose(rel[:2], [0.0, 0.5])


def test_another_day_and_no_overlap_are_refused(tmp_path):
    times, lat, lon = _samples()
    track = read_track(write_gpx(tmp_path / "a.gpx", T0, times, lat, lon))
    np.testing.assert_allclose(video_times(track, T0 - datetime.timedelta(seconds=5), 60.0)[:2], [5.0, 5.5])
    with pytest.raises(DatasetError, match="a track of another day is refused, not shifted"):
        video_times(track, T0 + datetime.timedelta(days=1), 60.0)
    with pytest.raises(DatasetError, match="does not overlap the video"):
        video_times(track, T0 + datetime.timedelta(hours=2), 60.0)
    with pytest.raises(ConfigError, match="--video-start"):
        video_times(track, None, 60.0)
    assert parse_start("2024-05-01T10:00:00") == T0  # no zone: UTC
    with pytest.raises(ConfigError, match="not an ISO-8601"):
        parse_start("yesterday")


@pytest.mark.parametrize("text, match", [
    ('<?xml version="1.0"?><!DOCTYPE gpx [<!ENTITY a "b">]><gpx></gpx>', "declares a DTD"),
    ('<gpx version="1.1"><trk><trkseg><trkpt lat="1" lon="2"></trkpt></trkseg></trk></gpx>', "has a time"),
    ("<gpx", "not a GPX file"),
    ("$GPGGA,bad\n", "no position with a time"),
    ("time,lat\n1,2\n", "needs a time column"),
    ("time,lat,lon\n1,2\n", "2 fields"),
    ("time,lat,lon\nnoon,2,3\n", "neither seconds nor an ISO-8601"),
    ("time,lat,lon\n1,95,3\n", "out of range"),
    ("time,lat,lon\n1,2,x\n", "not two numbers"),
    ("time,lat,lon\n1,2,3\n2024-05-01T10:00:00Z,2,3\n", "one kind per track"),
])
def test_refusals(tmp_path, text, match):
    p = tmp_path / "t.txt"
    p.write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_track(p)


def _good(kind: str) -> bytes:
    times, lat, lon = _samples(6)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"good.{kind}"
        {"gpx": lambda: write_gpx(p, T0, times, lat, lon), "nmea": lambda: write_nmea(p, T0, times, lat, lon),
         "csv": lambda: write_track_csv(p, times, lat, lon, t0=T0)}[kind]()
        return p.read_bytes()


@pytest.mark.parametrize("kind", ["gpx", "nmea", "csv"])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzzed_tracks_read_or_refuse(tmp_path, kind, data):
    bad = data.draw(mutated(_good(kind)))
    track = read_mutated(read_track, tmp_path / f"bad.{kind}", bad)
    if track is not None:
        assert np.isfinite(track.times).all() and (np.diff(track.times) > 0).all()
        assert track.coords.shape == (len(track.times), 2)


def test_why_no_frame_lies_on_the_track():
    ms = np.arange(0, 20000, 100) / 1.0  # a 20 s track written in milliseconds
    assert in_milliseconds(ms, 20.0) and not in_milliseconds(np.arange(0, 20, 0.1), 20.0)
    assert "times in milliseconds?" in why_outside(ms, 20.0, 10.0)
    gap = np.array([-5.0, 0.0, 60.0, 61.0])  # the 20 s video falls in a 60 s gap
    said = why_outside(gap, 20.0, 10.0)
    assert "inside a gap of the track of 60 s, longer than the 10 s a frame is interpolated across" in said
    later = np.arange(100.0, 130.0)
    assert "do not overlap the video's 0 .. 20.0 s" in why_outside(later, 20.0, 10.0)


@pytest.mark.parametrize("metres, outcome", [(0.0, "silent"), (110.0, "warned"), (5000.0, "refused")])
def test_two_fixes_at_one_time_are_warned_or_refused(tmp_path, caplog, metres, outcome):
    """Two receivers merged: a second fix at t = 1.5 s, ``metres`` north of the first; the first is used."""
    lat, lon = route(30)
    times = list(np.arange(30) / 10) + [1.5]
    lat, lon = np.append(lat, lat[15] + metres / 111320.0), np.append(lon, lon[15])
    path = write_track_csv(tmp_path / "dup.csv", times, lat, lon)
    if outcome == "refused":
        with pytest.raises(DatasetError, match=r"1 sample repeats a time with another position, up to 5000 m apart "
                           r"\(at 1.5 s\): two receivers merged\?"):
            read_track(path)
        return
    with caplog.at_level("WARNING"):
        track = read_track(path)
    assert len(track.times) == 30 and track.coords[15, 0] == pytest.approx(lat[15])
    assert ("up to 110 m apart (at 1.5 s)" in caplog.text) == (outcome == "warned"), caplog.text


@pytest.mark.parametrize("sep, bom", [(";", ""), ("\t", ""), (",", "\ufeff"), (";", "\ufeff")])
def test_csv_tracks_read_as_positions_csvs_do(tmp_path, sep, bom):
    times, lat, lon = _samples(6)
    want = read_track(write_track_csv(tmp_path / "plain.csv", times, lat, lon))
    text = (tmp_path / "plain.csv").read_text().replace(",", sep).replace("time", "Time", 1)
    (tmp_path / "other.csv").write_text(bom + text, encoding="utf-8")
    got = read_track(tmp_path / "other.csv")
    np.testing.assert_array_equal(got.times, want.times)
    np.testing.assert_array_equal(got.coords, want.coords)


def test_long_names_a_tracks_longitude_as_in_positions_csvs(tmp_path):
    times, lat, lon = _samples(6)
    want = read_track(write_track_csv(tmp_path / "plain.csv", times, lat, lon))
    (tmp_path / "long.csv").write_text((tmp_path / "plain.csv").read_text().replace(",lon", ",long", 1))
    np.testing.assert_array_equal(read_track(tmp_path / "long.csv").coords, want.coords)


def test_decimal_commas_in_a_track_are_named(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("time;lat;lon\n0;63,43;10,39\n")
    with pytest.raises(DatasetError, match="decimal commas"):
        read_track(p)


@pytest.mark.parametrize("per_second, unit", [(1, "seconds"), (1e3, "milliseconds"), (1e6, "microseconds"),
                                              (1e9, "nanoseconds")])
def test_unix_epoch_numbers_are_absolute_times(tmp_path, per_second, unit):
    times, lat, lon = _samples(6)
    iso = read_track(write_track_csv(tmp_path / "iso.csv", times, lat, lon, t0=T0))
    stamps = [f"{(T0.timestamp() + t):.3f}" if per_second == 1 else f"{round((T0.timestamp() + t) * per_second)}"
              for t in times]  # seconds with decimals; the smaller units as integers, as loggers write them
    (tmp_path / "epoch.csv").write_text("timestamp,lat,lon\n" + "".join(
        f"{s},{a:.9f},{b:.9f}\n" for s, a, b in zip(stamps, lat, lon, strict=True)))
    track = read_track(tmp_path / "epoch.csv")
    assert track.absolute and track.epoch == unit
    np.testing.assert_allclose(track.times, iso.times, atol=1e-6)
    np.testing.assert_allclose(video_times(track, T0, 60.0), times, atol=1e-6)  # placed by the video's clock
    with pytest.raises(ConfigError, match=f"absolute times \\(Unix epoch {unit}: 2024-05-01 10:00:00 UTC on\\), "
                                          "but the video records no creation_time; give its start with --video-start"):
        video_times(track, None, 60.0)


def test_seconds_since_the_start_stay_relative(tmp_path):
    times, lat, lon = _samples(6)
    for offset in (0.0, 1e6, 3e8):  # however long the log ran before the video: never an epoch time
        track = read_track(write_track_csv(tmp_path / "rel.csv", times + offset, lat, lon))
        assert not track.absolute and not track.epoch


@pytest.mark.parametrize("per_second, unit", [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
def test_the_unit_of_times_since_the_start_is_guessed_from_the_ratio(per_second, unit):
    t = np.arange(0, 20, 0.1) * per_second  # a 20 s track since the video's start, in a smaller unit
    assert f"times in {unit}?" in why_outside(t, 20.0, 10.0)


def test_a_track_whole_hours_off_names_the_zone_or_the_video_clock(tmp_path):
    times, lat, lon = _samples(6)
    local = T0.replace(tzinfo=None) + datetime.timedelta(hours=2)  # 12:00 local (UTC+2) written without a zone
    p = tmp_path / "local.csv"
    p.write_text("time,lat,lon\n" + "".join(f"{(local + datetime.timedelta(seconds=t)).isoformat()},{a},{b}\n"
                                            for t, a, b in zip(times, lat, lon, strict=True)))
    track = read_track(p)
    assert not track.zoned
    with pytest.raises(DatasetError, match=r"2 h after the video's .*: local time\? its times name no zone and are "
                                           r"read as UTC \(hint: write them with their zone, e.g. "
                                           r"2024-05-01T12:00:00\+02:00\)"):
        video_times(track, T0, 60.0)
    gpx = read_track(write_gpx(tmp_path / "a.gpx", T0, times, lat, lon))  # zoned times; the video's clock 5:30 off
    with pytest.raises(DatasetError, match=r"5.5 h before .* \(hint: --video-start 2024-05-01T10:00:00Z"):
        video_times(gpx, T0 + datetime.timedelta(hours=5, minutes=30), 60.0)
    with pytest.raises(DatasetError, match=r"UTC \(hint: --video-start ISO if the video's clock is wrong\)"):
        video_times(gpx, T0 + datetime.timedelta(hours=2, minutes=10), 60.0)  # not whole hours: as before
    # of a two-video build, the side is named and the hint sets that video's start only (--video-start set both:
    # following it, the other video's track no longer overlapped)
    with pytest.raises(DatasetError, match=r"does not overlap the query video: .* 5.5 h before the query video's .* "
                                           r"\(hint: --video-start query=2024-05-01T10:00:00Z, or correct the "
                                           r"track's times\)"):
        video_times(gpx, T0 + datetime.timedelta(hours=5, minutes=30), 60.0, side="query")
    np.testing.assert_allclose(video_times(gpx, T0, 60.0), times)  # a right track: placed, nothing said


def test_a_track_covering_part_of_the_video_is_said_to_cover_it():
    """A track of the video's first half was said not to overlap it; now what it covers and the frames left out,
    before its start, after its end and in its gaps, counted from the frames' times."""
    frames = np.arange(300) / 10  # a 30 s video at 10 frames/s
    half = np.arange(150) / 10
    inside = frames <= half[-1]
    said = why_outside(half, 30.0, 10.0, frames, inside)
    assert said == "the track covers 0 .. 14.9 s of the video's 0 .. 30.0 s: the 150 frames after its end have no " \
        "position"
    middle = np.r_[np.arange(50, 100), np.arange(130, 200)] / 10.0  # 5 .. 20 s with a 3 s gap; --max-gap 2
    inside = np.zeros(300, bool)
    inside[50:100] = inside[130:200] = True
    said = why_outside(middle, 30.0, 2.0, frames, inside)
    assert said == "the track covers 5 .. 19.9 s of the video's 0 .. 30.0 s: 180 frames have no position (50 " \
        "before its start, 100 after its end, 30 in its gaps of more than 2 s (--max-gap))"
    assert "do not overlap" not in why_outside(half, 30.0, 10.0)  # without the frames: no counts, still true
    assert "do not overlap the video's 0 .. 20.0 s" in why_outside(np.arange(100.0, 130.0), 20.0, 10.0)
