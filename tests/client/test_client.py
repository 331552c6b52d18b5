"""``seqnet.client``: frames encoded as the server reads them, sessions, answers, refusals, reconnection."""

from __future__ import annotations

import http.server
import io
import json
import threading

import numpy as np
import pytest
from conftest import serving

from seqnet.client import Client, ClientError, encode_frame
from seqnet.core.errors import DatasetError


def test_frames_are_encoded_by_their_kind(tmp_path):
    body, kind = encode_frame([1, 2, 3])
    assert kind == "application/x-npy"
    back = np.load(io.BytesIO(body), allow_pickle=False)
    assert back.dtype == np.float32 and back.tolist() == [1.0, 2.0, 3.0]
    np.save(tmp_path / "d.npy", np.ones(4, np.float32))
    assert encode_frame(tmp_path / "d.npy") == ((tmp_path / "d.npy").read_bytes(), "application/x-npy")
    assert encode_frame(b"\x89PNG\r\n\x1a\nrest")[1] == "image/png"
    assert encode_frame(bytearray(b"\xff\xd8\xff\xe0rest"))[1] == "image/jpeg"
    assert encode_frame(b"RIFF\x10\x00\x00\x00WEBPVP8L")[1] == "image/webp"  # the server reads WEBP too
    with pytest.raises(ClientError, match="PNG, JPEG or WEBP"):
        encode_frame(b"GIF89a")
    with pytest.raises(ClientError, match="PNG, JPEG or WEBP"):
        encode_frame(b"RIFF\x10\x00\x00\x00WAVEfmt ")  # RIFF, but sound
    with pytest.raises(ClientError, match=r"shape \[D\]"):
        encode_frame(np.ones((2, 3)))
    with pytest.raises(DatasetError, match="not found"):
        encode_frame(tmp_path / "missing.png")
    for bad in ("ftp://example.org", "http://", "http://host:1/; a note", "http://host:1/\x00"):
        with pytest.raises(ClientError, match="http://host:port"):
            Client(bad)


def test_sessions_answers_and_refusals(serve_service, synth_dataset):
    q = synth_dataset.split("test").query.descriptors.astype(np.float32)
    loc = serve_service.localizer()
    want = [e.ref_frame if e.ref_index >= 0 else None for e in map(loc.step, q[:8])]
    with serving(serve_service, token="client-test-token-0123456789") as (url, api):
        client = Client(url, "client-test-token-0123456789")
        assert client.health()["frames"] == serve_service.frames
        assert [a["estimate"] for a in client.localize(q[:8])] == want
        assert len(api.sessions) == 0  # localize() deleted its session
        assert [client.send(f)["estimate"] for f in q[:8]] == want  # the client's own session
        assert len(api.sessions) == 1
        with client.session() as s:
            answers = list(s.stream(q[:3]))
            assert list(s) == answers and [a["frame"] for a in s] == [0, 1, 2]
            with pytest.raises(ClientError) as e:
                s.send(np.ones(serve_service.dim + 1, np.float32))
            assert e.value.status == 400 and "dimension mismatch" in e.value.message
        client.close()
        assert len(api.sessions) == 0
        assert "seqnet_serve_frames_total" in client.metrics()
        with pytest.raises(ClientError) as e:
            Client(url, "wrong").session()
        assert e.value.status == 401 and "token" in e.value.message
    with pytest.raises(ClientError) as e:
        Client(url).health()  # the server is gone
    assert e.value.status == 0 and "cannot reach" in str(e.value)


class _ClosingHandler(http.server.BaseHTTPRequestHandler):
    """Answers as if keeping the connection alive, then closes it (what a server does when a keep-alive ends)."""

    protocol_version = "HTTP/1.1"
    served: list[str] = []

    def do_POST(self):  # noqa: N802 - http.server's name
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        body = json.dumps({"session": "s1"} if self.path == "/v1/sessions" else {"frame": len(self.served)}).encode()
        self.served.append(self.path)
        self.send_response(201 if self.path == "/v1/sessions" else 200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)
        self.close_connection = True

    def log_message(self, *args):
        pass


def test_a_connection_the_server_closed_is_reopened_once():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _ClosingHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        s = Client(f"http://127.0.0.1:{server.server_address[1]}").session()
        assert [s.send(np.zeros(3))["frame"] for _ in range(3)] == [1, 2, 3]
        assert _ClosingHandler.served == ["/v1/sessions"] + ["/v1/sessions/s1/frames"] * 3
    finally:
        server.shutdown()
        server.server_close()
