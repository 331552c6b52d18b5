"""Every answer of the API: auth, sessions, frames, and each refusal as JSON with its status (never a 500)."""

from __future__ import annotations

import http.client
import io
import json
import urllib.parse

import numpy as np
import pytest
from conftest import serving

TOKEN = "s3cret-token-of-the-tests-0123456789"


def call(url, method, path, body=None, headers=None, token=TOKEN):
    """``(status, JSON or text)`` of one request."""
    u = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    h = {**({"Authorization": f"Bearer {token}"} if token else {}), **(headers or {})}
    try:
        conn.request(method, path, body=body, headers=h)
        r = conn.getresponse()
        data = r.read()
    finally:
        conn.close()
    kind = r.getheader("Content-Type", "")
    return r.status, json.loads(data) if kind.startswith("application/json") and data else data.decode()


def npy(a) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(a), allow_pickle=True)
    return buf.getvalue()


NPY = {"Content-Type": "application/x-npy"}


@pytest.fixture(scope="module")
def server(serve_service):
    with serving(serve_service, token=TOKEN, max_sessions=3, max_body_mb=0.01) as (url, api):
        yield url, api


def test_health_needs_no_token_and_the_rest_does(server, serve_service):
    url, _ = server
    assert call(url, "GET", "/health", token=None) == (200, {"status": "ok", "map": "map",
                                                              "frames": serve_service.frames})
    for token in (None, "wrong", TOKEN[:-1], TOKEN + "x"):
        for method, path in (("POST", "/v1/sessions"), ("GET", "/metrics"), ("GET", "/v1/state"),
                             ("POST", "/v1/sessions/x/frames"), ("DELETE", "/v1/sessions/x")):
            status, body = call(url, method, path, token=token)
            assert status == 401 and "token" in body["error"], (method, path, token)
    assert call(url, "GET", "/health", headers={"Authorization": f"Basic {TOKEN}"}, token=None)[0] == 200
    assert call(url, "GET", "/metrics", headers={"Authorization": f"Basic {TOKEN}"}, token=None)[0] == 401


def test_a_session_answers_frames_and_is_deleted(server, synth_dataset):
    url, _ = server
    status, body = call(url, "POST", "/v1/sessions")
    assert status == 201 and set(body) == {"session"}
    sid = body["session"]
    q = synth_dataset.split("test").query.descriptors
    answers = [call(url, "POST", f"/v1/sessions/{sid}/frames", npy(q[i].astype(np.float32)), NPY)
               for i in range(5)]
    assert all(s == 200 for s, _ in answers)
    keys = {"frame", "estimate", "estimate_name", "score", "confidence", "position", "latency_ms", "full_window"}
    assert all(set(a) == keys for _, a in answers)
    assert [a["frame"] for _, a in answers] == [0, 1, 2, 3, 4]
    assert answers[0][1]["estimate"] is None and not answers[0][1]["full_window"]  # L = 4: no answer yet
    last = answers[-1][1]
    assert last["full_window"] and isinstance(last["estimate"], int) and len(last["position"]) == 2
    assert last["estimate_name"].startswith("reference_") and 0 <= last["confidence"] <= 1
    assert call(url, "DELETE", f"/v1/sessions/{sid}") == (204, "")
    assert call(url, "DELETE", f"/v1/sessions/{sid}")[0] == 404
    status, body = call(url, "POST", f"/v1/sessions/{sid}/frames", npy(q[0].astype(np.float32)), NPY)
    assert status == 404 and "unknown session" in body["error"]


def bad_bodies(dim: int) -> dict[str, bytes]:
    good = np.ones(dim, np.float32)
    truncated = npy(good)[:-3]
    return {"garbage": b"\x00garbage" * 10, "empty": b"", "wrong D": npy(np.ones(dim + 1, np.float32)),
            "NaN": npy(np.r_[good[:-1], np.nan].astype(np.float32)), "inf": npy(np.r_[good[:-1], np.inf]),
            "beyond float32": npy(np.concatenate([good[:-1], [1e300]]).astype(np.float64)),
            "2-D": npy(good[None]), "ints": npy(np.ones(dim, int)),
            "objects": npy(np.array([object()] * dim)), "truncated": truncated, "trailing": npy(good) + b"xx",
            "bad header": b"\x93NUMPY\x01\x00\x10\x00{'descr': 1}    \n" + bytes(4 * dim),
            "npz": b"PK\x03\x04" + bytes(40)}


def test_bad_frames_are_400_and_leave_the_session_as_it_was(server, serve_service, synth_dataset):
    url, api = server
    q = synth_dataset.split("test").query.descriptors.astype(np.float32)
    sid = call(url, "POST", "/v1/sessions")[1]["session"]
    first = [call(url, "POST", f"/v1/sessions/{sid}/frames", npy(q[i]), NPY)[1] for i in range(3)]
    for name, body in bad_bodies(serve_service.dim).items():
        status, answer = call(url, "POST", f"/v1/sessions/{sid}/frames", body, NPY)
        assert status == 400 and answer["error"], (name, answer)
    rest = [call(url, "POST", f"/v1/sessions/{sid}/frames", npy(q[i]), NPY)[1] for i in range(3, 6)]
    loc = serve_service.localizer()
    want = [loc.step(q[i]) for i in range(6)]
    assert [a["estimate"] for a in first + rest] == [e.ref_frame if e.ref_index >= 0 else None for e in want]
    assert [a["frame"] for a in first + rest] == list(range(6))
    call(url, "DELETE", f"/v1/sessions/{sid}")
    assert 500 not in api.metrics.requests


def test_wrong_type_too_large_and_too_many(server, serve_service):
    url, api = server
    sid = call(url, "POST", "/v1/sessions")[1]["session"]
    frames = f"/v1/sessions/{sid}/frames"
    for kind in (None, "text/plain", "application/json", "image/gif", "application/octet-stream"):
        status, body = call(url, "POST", frames, npy(np.ones(serve_service.dim, np.float32)),
                            {"Content-Type": kind} if kind else {})
        assert status == 415 and "content type" in body["error"], kind
    big = bytes(20_000)  # the limit is 0.01 MB
    assert call(url, "POST", frames, big, NPY)[0] == 413  # refused from its Content-Length
    u = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)  # chunked: refused while it arrives
    conn.request("POST", frames, body=iter([bytes(4000)] * 5), encode_chunked=True,
                 headers={"Authorization": f"Bearer {TOKEN}", **NPY, "Transfer-Encoding": "chunked"})
    r = conn.getresponse()
    assert r.status == 413 and "limit" in json.loads(r.read())["error"]
    conn.close()
    assert call(url, "POST", frames, b"x", {**NPY, "Content-Length": "abc"})[0] in (400, 413)
    ids = [sid] + [call(url, "POST", "/v1/sessions")[1]["session"] for _ in range(2)]
    status, body = call(url, "POST", "/v1/sessions")
    assert status == 429 and "most sessions" in body["error"]
    for s in ids:
        assert call(url, "DELETE", f"/v1/sessions/{s}")[0] == 204
    assert call(url, "GET", "/nowhere")[0] == 404 and call(url, "GET", "/v1/sessions")[0] == 405
    assert 500 not in api.metrics.requests


def test_metrics_are_prometheus_text(server):
    url, _ = server
    status, text = call(url, "GET", "/metrics")
    assert status == 200
    lines = text.splitlines()
    assert "# TYPE seqnet_serve_frame_latency_seconds histogram" in lines
    assert any(line.startswith('seqnet_serve_frames_total{outcome="ok"} ') for line in lines)
    assert any(line.startswith("seqnet_serve_sessions ") for line in lines)
    hist = "seqnet_serve_frame_latency_seconds"
    buckets = [int(line.rsplit(" ", 1)[1]) for line in lines if line.startswith(f"{hist}_bucket")]
    assert buckets == sorted(buckets) and buckets[-1] == int(next(
        line.rsplit(" ", 1)[1] for line in lines if line.startswith(f"{hist}_count")))
    assert not any(line.startswith('seqnet_serve_requests_total{code="500"}') for line in lines)
