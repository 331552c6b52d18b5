"""Sessions in parallel: each its own causal window, its answers those of the localiser alone on its frames."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from conftest import serving

from seqnet.client import Client
from seqnet.serve.errors import HttpError
from seqnet.serve.sessions import Sessions


def alone(service, frames):
    """The answers of a localiser of the service's settings stepping ``frames`` on its own (as seqnet localize)."""
    loc = service.localizer()
    return [(e.ref_frame if e.ref_index >= 0 else None, e.full_window, e.confidence) for e in map(loc.step, frames)]


def seen(answers):
    return [(a["estimate"], a["full_window"], a["confidence"]) for a in answers]


def test_interleaved_sessions_equal_the_localizer_alone(serve_service, synth_dataset):
    q = synth_dataset.split("test").query.descriptors.astype(np.float32)
    a_frames, b_frames = q[:12], q[::-1][:12]  # two streams through different places
    with serving(serve_service) as (url, api):
        client = Client(url)
        a, b = client.session(), client.session()
        got_a, got_b = [], []
        for fa, fb in zip(a_frames, b_frames, strict=True):
            got_a.append(a.send(fa))
            got_b.append(b.send(fb))
        assert seen(got_a) == alone(serve_service, a_frames)
        assert seen(got_b) == alone(serve_service, b_frames)
        assert seen(got_a) != seen(got_b)
        assert len(api.sessions) == 2
        a.close(), b.close()


def test_concurrent_sessions_with_bad_frames_between(serve_service, synth_dataset):
    q = synth_dataset.split("test").query.descriptors.astype(np.float32)
    streams = [np.roll(q, 7 * i, axis=0)[:15] for i in range(4)]
    results, errors = {}, []
    with serving(serve_service) as (url, api):
        def run(i):
            try:
                with Client(url).session() as s:
                    out = []
                    for j, f in enumerate(streams[i]):
                        if i % 2 and j % 4 == 1:  # a bad frame between good ones: refused, nothing changes
                            try:
                                s.send(np.full_like(f, np.nan))
                            except Exception as e:  # noqa: BLE001 - collected, checked below
                                errors.append(getattr(e, "status", e))
                        out.append(s.send(f))
                    results[i] = out
            except Exception as e:  # noqa: BLE001 - a thread's failure is the test's
                results[i] = e

        threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert 500 not in api.metrics.requests
    assert errors == [400] * 8
    for i in range(4):
        assert seen(results[i]) == alone(serve_service, streams[i]), i


def test_sessions_expire_when_idle_and_are_bounded():
    now = [0.0]
    s = Sessions(2, idle_s=10, clock=lambda: now[0])
    a = s.add(object())
    now[0] = 6
    b = s.add(object())
    with pytest.raises(HttpError) as e:
        s.add(object())
    assert e.value.status == 429
    now[0] = 12  # a: idle 12 s; b: 6 s
    assert s.expire() == [a.id] and len(s) == 1
    assert s.get(b.id) is b
    with pytest.raises(HttpError) as e:
        s.get(a.id)
    assert e.value.status == 404 and "expired" in e.value.message
    now[0] = 30
    s.add(object())  # room made by expiring b first
    assert b.id not in s.live and s.expired == 2 and s.created == 3


def test_the_server_expires_idle_sessions(serve_service):
    import time

    with serving(serve_service, session_idle_s=0.2) as (url, api):
        client = Client(url)
        s = client.session()
        deadline = time.monotonic() + 5
        while len(api.sessions) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(api.sessions) == 0 and api.sessions.expired == 1
        with pytest.raises(Exception, match="unknown session") as e:
            s.send(np.zeros(serve_service.dim, np.float32))
        assert e.value.status == 404
