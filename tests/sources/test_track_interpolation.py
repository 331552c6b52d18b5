"""Positions at frame times (vectorised) against a naive loop; frames kept per second or per metre."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.sources.sampling import every_metres, every_seconds
from seqnet.sources.tracks.interpolate import EDGE, at_times


def naive(times, xy, t, max_gap):
    out, inside = np.full((len(t), 2), np.nan), np.zeros(len(t), bool)
    for i, ti in enumerate(t):
        if times[0] - EDGE <= ti < times[0]:
            ti = times[0]
        if times[-1] < ti <= times[-1] + EDGE:
            ti = times[-1]
        for k in range(len(times)):
            if times[k] == ti:
                out[i], inside[i] = xy[k], True
                break
            if k + 1 < len(times) and times[k] < ti < times[k + 1] and times[k + 1] - times[k] <= max_gap:
                w = (ti - times[k]) / (times[k + 1] - times[k])
                out[i], inside[i] = (1 - w) * xy[k] + w * xy[k + 1], True
                break
    return out, inside


@pytest.mark.parametrize("seed", range(5))
def test_interpolation_equals_a_naive_loop(seed):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.1, 3.0, 40)) + rng.uniform(-5, 5)
    xy = rng.normal(size=(40, 2)) * 100
    t = np.concatenate([rng.uniform(times[0] - 10, times[-1] + 10, 200), times[::7], [times[0] - EDGE / 2]])
    got, inside = at_times(times, xy, t, max_gap=2.0)
    want, want_inside = naive(times, xy, t, 2.0)
    np.testing.assert_array_equal(inside, want_inside)
    np.testing.assert_allclose(got[inside], want[inside], rtol=1e-12, atol=1e-9)
    assert np.isnan(got[~inside]).all() and (~inside).sum() > 10  # outside: before, after, and in gaps


def test_one_sample_track():
    got, inside = at_times(np.array([5.0]), np.array([[1.0, 2.0]]), np.array([4.0, 5.0, 6.0]))
    assert inside.tolist() == [False, True, False] and got[1].tolist() == [1.0, 2.0]


def test_every_metres_at_ten_metre_spacing_keeps_half():
    noise = 1e-9 * np.random.default_rng(0).normal(size=(100, 2))
    xy = np.stack([np.arange(100) * 10.0, np.zeros(100)], axis=1) + noise
    keep = every_metres(xy, 20.0)
    assert len(keep) == 50 and keep[:3].tolist() == [0, 2, 4]
    assert len(every_metres(xy, 10.0)) == 100 and len(every_metres(xy, 1000.0)) == 1
    with pytest.raises(ConfigError):
        every_metres(xy, 0.0)


def test_every_seconds_keeps_the_first_frame_of_each_interval():
    times = np.arange(0, 10, 0.1)  # 10 fps for 10 s
    assert len(every_seconds(times, 2.0)) == 20 and every_seconds(times, 2.0)[:3].tolist() == [0, 5, 10]
    assert len(every_seconds(times, 100.0)) == 100  # faster than the video: every frame
    vfr = np.array([0.0, 0.05, 0.6, 0.61, 0.62, 2.5])
    assert every_seconds(vfr, 2.0).tolist() == [0, 2, 5]


def _naive_every_metres(xy, metres):
    keep = [0]
    for j in range(1, len(xy)):
        along = sum(np.linalg.norm(xy[k + 1] - xy[k]) for k in range(keep[-1], j))
        if along >= 0.995 * metres and np.linalg.norm(xy[j] - xy[keep[-1]]) >= 0.995 * metres:
            keep.append(j)
    return keep


def test_every_metres_keeps_no_frame_at_a_standstill_with_gps_jitter():
    rng = np.random.default_rng(1)
    s = np.concatenate([np.arange(80) * 1.0, np.full(300, 80.0), 80 + np.arange(1, 81) * 1.0])  # 10 m/s, a stop
    xy = np.stack([s, np.zeros_like(s)], axis=1) + rng.normal(0, 0.5, (len(s), 2))  # 0.5 m GPS noise
    keep = every_metres(xy, 5.0)
    stopped = ((keep >= 80) & (keep < 380)).sum()
    assert stopped <= 1, stopped  # 30 s at a red light: no copies of one place (summing the jitter: about 190)
    assert 0.8 * 160 / 5 <= len(keep) <= 160 / 5 + 1  # about one per 5 m of the 160 m driven (noise overshoots)
    assert keep.tolist() == _naive_every_metres(xy, 5.0)
    clean = every_metres(np.stack([s, np.zeros_like(s)], axis=1), 5.0)  # without noise: exactly one per 5 m
    assert len(clean) == 160 / 5 + 1 and ((clean >= 80) & (clean < 380)).sum() == 1  # 80 m: where the stop begins


def test_every_metres_on_a_curve_and_against_a_naive_loop():
    a = np.arange(200) * 2 * np.arcsin(0.05)  # 10 m steps (chords) on a circle of radius 100 m
    xy = 100.0 * np.stack([np.cos(a), np.sin(a)], axis=1)
    keep = every_metres(xy, 20.0)
    assert np.diff(keep).tolist() == [2] * 99  # chords of 19.98 m count as 20 m
    rng = np.random.default_rng(3)
    walk = np.cumsum(rng.normal(0, 3, (500, 2)), axis=0)
    assert every_metres(walk, 7.0).tolist() == _naive_every_metres(walk, 7.0)
