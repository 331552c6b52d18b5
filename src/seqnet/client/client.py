"""``seqnet.client.Client``: sessions and frames of a ``seqnet serve`` over HTTP (standard library only).

Example::

    from seqnet.client import Client

    client = Client("http://127.0.0.1:8080", token)
    with client.session() as s:                 # one causal window, deleted on exit
        for answer in s.stream(frames):         # descriptors [D], PNG / JPEG bytes, or file paths
            print(answer["frame"], answer["estimate"], answer["confidence"])

A session keeps one HTTP connection (its frames in order); a refusal is a :class:`ClientError` with the server's
status and message.
"""

from __future__ import annotations

import http.client
import io
import json
import os
import urllib.parse
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from ..core.errors import DatasetError, SeqnetError
from ..security.inputs import read_bytes

MAX_FRAME_BYTES = 64 << 20  # a frame file larger than this is refused before it is read
MAGIC = {b"\x89PNG\r\n\x1a\n": "image/png", b"\xff\xd8\xff": "image/jpeg", b"\x93NUMPY": "application/x-npy"}
STALE = (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError)  # a kept-alive connection closed


class ClientError(SeqnetError):
    """A request the server refused (``status``: its HTTP status; 0: no answer) with its message."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(f"{status}: {message}" if status else message)
        self.status, self.message = int(status), message


def encode_frame(frame: Any) -> tuple[bytes, str]:
    """``(body, content type)`` of a frame: a descriptor (array-like ``[D]``) as ``.npy`` float32, PNG / JPEG / WEBP /
    ``.npy`` bytes as they are, or a file path (``str`` / ``Path``) read and sent as its bytes are."""
    if isinstance(frame, (str, os.PathLike)):
        frame = read_bytes(frame, MAX_FRAME_BYTES, "frame file", DatasetError)
    if isinstance(frame, (bytes, bytearray, memoryview)):
        data = bytes(frame)
        kind = next((k for magic, k in MAGIC.items() if data.startswith(magic)), None)
        if kind is None and data[:4] == b"RIFF" and data[8:12] == b"WEBP":  # RIFF, size, WEBP: the server reads it
            kind = "image/webp"
        if kind is None:
            raise ClientError(0, "a frame given as bytes must be a PNG, JPEG or WEBP image or a .npy array")
        return data, kind
    arr = np.asarray(frame, dtype=np.float32)
    if arr.ndim != 1:
        raise ClientError(0, f"a descriptor frame has shape [D]; got {list(arr.shape)}")
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, allow_pickle=False)
    return buf.getvalue(), "application/x-npy"


class _Connection:
    """One kept-alive HTTP(S) connection to the server, re-opened once when the server had closed it."""

    def __init__(self, url: urllib.parse.SplitResult, headers: dict[str, str], timeout: float) -> None:
        self.url, self.headers, self.timeout = url, headers, timeout
        self.conn: http.client.HTTPConnection | None = None

    def request(self, method: str, path: str, body: bytes | None = None,
                content_type: str | None = None) -> tuple[int, Any]:
        headers = {**self.headers, **({"Content-Type": content_type} if content_type else {})}
        for attempt in (0, 1):
            reused = self.conn is not None
            if self.conn is None:
                kind = http.client.HTTPSConnection if self.url.scheme == "https" else http.client.HTTPConnection
                self.conn = kind(self.url.hostname, self.url.port, timeout=self.timeout)
            try:
                self.conn.request(method, self.url.path.rstrip("/") + path, body=body, headers=headers)
                response = self.conn.getresponse()
                data = response.read()
                break
            except STALE as e:
                self.close()
                if not reused or attempt:
                    raise ClientError(0, f"no answer from {self.url.geturl()}: {e}") from e
            except OSError as e:
                self.close()
                raise ClientError(0, f"cannot reach {self.url.geturl()}: {e}") from e
            except http.client.HTTPException as e:  # not HTTP: a truncated or malformed answer
                self.close()
                raise ClientError(0, f"no valid HTTP answer from {self.url.geturl()}: {e!r}") from e
        return response.status, _decode(response.status, data, response.getheader("Content-Type", ""))

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def _decode(status: int, data: bytes, kind: str) -> Any:
    """The JSON (or text) of an answer; a refusal is a :class:`ClientError` with the server's message."""
    value: Any = data.decode("utf-8", "replace")
    if kind.startswith("application/json") and data:
        try:
            value = json.loads(data)
        except ValueError:
            pass
    if status >= 400:
        message = value.get("error") if isinstance(value, dict) else str(value)[:300]
        raise ClientError(status, str(message))
    return value


class Session:
    """One session (its own causal window) on the server: :meth:`send` a frame, get its answer; :meth:`stream`
    frames, iterate their answers; :attr:`answers`: every answer so far, in order."""

    def __init__(self, client: Client, sid: str) -> None:
        self.client, self.id = client, sid
        self.answers: list[dict[str, Any]] = []
        self._conn = client.connection()

    def send(self, frame: Any) -> dict[str, Any]:
        """The server's answer for the next frame (see :func:`encode_frame` for what a frame may be)."""
        body, kind = encode_frame(frame)
        _, answer = self._conn.request("POST", f"/v1/sessions/{self.id}/frames", body, kind)
        self.answers.append(answer)
        return answer

    def stream(self, frames: Iterable[Any]) -> Iterator[dict[str, Any]]:
        """The answers of ``frames``, sent one by one in order, as they come."""
        for frame in frames:
            yield self.send(frame)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return iter(list(self.answers))

    def close(self) -> None:
        """Delete the session on the server (already gone: nothing to do) and close its connection."""
        try:
            self._conn.request("DELETE", f"/v1/sessions/{self.id}")
        except ClientError as e:
            if e.status != 404:
                raise
        finally:
            self._conn.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Client:
    """A ``seqnet serve`` at ``url`` (``http://host:port`` or ``https://…`` behind a TLS proxy), with its
    ``token`` (None: a server started with ``--no-auth``); ``timeout``: seconds per request."""

    def __init__(self, url: str, token: str | None = None, timeout: float = 30.0) -> None:
        self.url = urllib.parse.urlsplit(url)
        if self.url.scheme not in ("http", "https") or not self.url.hostname or any(c.isspace() or not c.isprintable()
                                                                                     for c in url):
            raise ClientError(0, f"the server's address must be http://host:port or https://host, got {url!r}")
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.timeout = float(timeout)
        self._default: Session | None = None
        self._conn = self.connection()

    def connection(self) -> _Connection:
        return _Connection(self.url, self.headers, self.timeout)

    def health(self) -> dict[str, Any]:
        """``GET /health``: status, map name, its frames."""
        return self._conn.request("GET", "/health")[1]

    def metrics(self) -> str:
        """``GET /metrics``: the Prometheus text."""
        return self._conn.request("GET", "/metrics")[1]

    def session(self) -> Session:
        """A new session (``POST /v1/sessions``); close it (or use ``with``) when done."""
        _, value = self._conn.request("POST", "/v1/sessions")
        return Session(self, str(value["session"]))

    def send(self, frame: Any) -> dict[str, Any]:
        """The answer for ``frame`` in this client's own session (created on the first frame)."""
        if self._default is None:
            self._default = self.session()
        return self._default.send(frame)

    def localize(self, frames: Iterable[Any]) -> Iterator[dict[str, Any]]:
        """The answers of ``frames`` in a session of their own (deleted at the end)."""
        with self.session() as s:
            yield from s.stream(frames)

    def close(self) -> None:
        """Delete this client's own session, if any, and close the connections."""
        if self._default is not None:
            self._default.close()
            self._default = None
        self._conn.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
