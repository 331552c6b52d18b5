"""A constant clock offset between a track and the answers: found as a loop finds it, said with the hint that fits
the track's times (numbers: shift them; absolute: the video's clock), for localize and for eval on a video
dataset."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from seqnet.sources.tracks.offset import clock_offset, dataset_offset_note, offset_note


def _naive_offset(frame_t, est_xy, track_t, track_xy):
    offs = []
    for t, e in zip(frame_t, est_xy, strict=True):
        if not np.isfinite(e).all():
            continue
        d = [np.hypot(*(e - p)) for p in track_xy]
        offs.append(track_t[int(np.argmin(d))] - t)
    med = float(np.median(offs))
    spread = float(np.median([abs(o - med) for o in offs]))
    return med if abs(med) >= 1.0 and spread <= max(0.25 * abs(med), 1.0) else None


@pytest.mark.parametrize("shift", [-5.0, -1.0, 0.0, 0.5, 3.0])
def test_clock_offset_matches_a_loop(rng, shift):
    track_t = np.arange(0, 30, 0.1)
    track_xy = np.stack([track_t * 10.0, 30 * np.sin(track_t / 2)], axis=1)
    frame_t = np.arange(0, 20, 0.1)
    est = np.interp(frame_t + shift, track_t, track_xy[:, 0]), np.interp(frame_t + shift, track_t, track_xy[:, 1])
    est_xy = np.stack(est, axis=1) + rng.normal(0, 1.0, (len(frame_t), 2))
    est_xy[::7] = np.nan  # unanswered frames
    got = clock_offset(frame_t, est_xy, track_t, track_xy)
    assert got == _naive_offset(frame_t, est_xy, track_t, track_xy)
    if abs(shift) >= 1:
        assert got == pytest.approx(shift, abs=0.15)
    else:
        assert got is None


def test_random_estimates_have_no_clock_offset(rng):
    track_t = np.arange(0, 30, 0.1)
    track_xy = np.stack([track_t * 10.0, np.zeros_like(track_t)], axis=1)
    est = track_xy[rng.integers(0, len(track_t), 200)]
    assert clock_offset(np.arange(0, 20, 0.1), est, track_t, track_xy) is None
    assert clock_offset(np.arange(5.0), est[:5], track_t, track_xy) is None  # too few frames


def test_offset_note_says_which_way():
    assert "5.0 s behind the track" in offset_note(-5.0) and "5.0 s late?" in offset_note(-5.0)
    assert "3.0 s ahead of the track" in offset_note(3.0) and "3.0 s early?" in offset_note(3.0)
    assert offset_note(None) is None
    numeric = offset_note(1.0, numeric=True)  # a CSV of seconds since the start: --video-start cannot help
    assert "the track's times run 1.0 s late (hint: subtract 1.0 s from its times" in numeric
    assert "--video-start does not move" in numeric and "is --video-start" not in numeric


def _video_dataset(shift: float, kind: str = "seconds", videos: bool = True):
    """A dataset as ``from-video`` writes it: 200 frames at 10 fps along a road at 10 m/s; the query frames are
    placed ``shift`` s late along it (their track runs late), names are video times."""
    t = np.arange(200) / 10.0
    road = np.stack([10.0 * t, 30 * np.sin(t / 2)], axis=1)
    q_pos = np.stack([np.interp(t + shift, t, road[:, 0]), np.interp(t + shift, t, road[:, 1])], axis=1)
    extra = {"videos": {side: {"positions": f"{side}.csv", "track_times": kind} for side in ("reference", "query")}}
    side = SimpleNamespace(names=[f"{x:.6f}" for x in t], positions=q_pos)
    return SimpleNamespace(query=side, reference=SimpleNamespace(names=side.names, positions=road), radius=5.0,
                           position_unit="metres", extra=extra if videos else {})


def test_eval_says_a_query_track_a_constant_time_off():
    q, r = np.arange(200), np.arange(200)
    top = np.arange(200)  # every answer right: the query frame i shows reference place i
    note = dataset_offset_note(_video_dataset(1.5), q, r, top)
    assert "of 200 correct), but they sit 1.5 s behind the query frames along the query track" in note
    assert "hint: add 1.5 s to the query track's times" in note and "--video-start does not move them" in note
    absolute = dataset_offset_note(_video_dataset(-2.0, "absolute"), q, r, top)
    assert "subtract 2.0 s from the query track's times" in absolute and "creation_time" in absolute
    assert dataset_offset_note(_video_dataset(0.0), q, r, top) is None  # right data: nothing said
    assert dataset_offset_note(_video_dataset(1.5, videos=False), q, r, top) is None  # not from videos
    rng = np.random.default_rng(0)
    assert dataset_offset_note(_video_dataset(1.5), q, r, rng.integers(0, 200, 200)) is None  # random answers


def test_estimates_off_a_short_track_are_not_timed_by_it():
    """A query track kept for 3 s (15 frames) while the answers sit 37 s along the route: every estimate's nearest
    fix is the track's end, so 'the track runs 1.4 s late' was said beside the exact 185-frame shift; with the
    radius as ``max_dist`` nothing is said (the estimates lie off the track)."""
    import numpy as np

    from seqnet.sources.tracks.offset import clock_offset

    t = np.arange(15) / 5.0  # 15 frames at 5 fps
    track_xy = np.stack([t * 50.0, np.zeros_like(t)], axis=1)  # 10 m per frame
    est = np.stack([(t + 37.0) * 50.0, np.zeros_like(t)], axis=1)  # 37 s along the route
    assert clock_offset(t, est, t, track_xy) is not None  # the old reading: a figure from the track's end
    assert clock_offset(t, est, t, track_xy, max_dist=10.0) is None
    near = np.stack([(t + 1.0) * 50.0, np.zeros_like(t)], axis=1)  # 1 s along: on the track, timed
    assert clock_offset(t[:10], near[:10], t, track_xy, max_dist=10.0) == pytest.approx(1.0)
