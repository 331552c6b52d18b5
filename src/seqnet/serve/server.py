"""Running the app under uvicorn: listen, answer, and on SIGTERM (or SIGINT) stop accepting, finish the requests
in flight (at most :data:`DRAIN_S` seconds), and return. SIGTERM is a normal stop (``seqnet serve`` exits 0);
SIGINT is re-raised after the drain, as uvicorn does (exit 130).

uvicorn runs on uvloop with the httptools parser when they are installed (the ``serve`` extra installs them), else
on asyncio with h11. While :func:`serve` runs, the interpreter switches threads every :data:`SWITCH_S` seconds
instead of Python's 5 ms: the workers localise in Python, holding the GIL most of the time, and with the default
the event loop (reading bodies, writing answers) waits up to 5 ms for it at each step of every request.
"""

from __future__ import annotations

import signal
import socket
import sys
from collections.abc import Callable
from typing import Any

import uvicorn

from ..core.errors import ConfigError
from .app import make_app
from .service import Service
from .settings import ServeSettings

DRAIN_S = 30  # the longest a stop waits for requests in flight
SWITCH_S = 0.0005  # the GIL's switch interval while serving (Python's default: 0.005)


class _Server(uvicorn.Server):
    """uvicorn's server, with SIGTERM a normal stop (not re-raised once the requests in flight are done) and a
    callback once it listens (with the port it got: ``port=0`` picks a free one)."""

    def __init__(self, config: uvicorn.Config, started: Callable[[int], None] | None = None) -> None:
        super().__init__(config)
        self._started = started

    def handle_exit(self, sig: int, frame: Any) -> None:
        super().handle_exit(sig, frame)
        if sig == signal.SIGTERM:
            self._captured_signals = [s for s in self._captured_signals if s != signal.SIGTERM]

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        if self._started is not None and self.started and sockets:
            self._started(int(sockets[0].getsockname()[1]))


def listen(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` (``port`` 0: a free one); an address in use or not of this machine is
    an :class:`OSError` here, before the server starts."""
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as e:
        raise ConfigError(f"--host {host!r} is not an address of this machine ({e.strerror})") from e
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
    except OSError:
        sock.close()
        raise
    return sock


def build_server(service: Service, settings: ServeSettings,
                 started: Callable[[int], None] | None = None) -> uvicorn.Server:
    """The uvicorn server of ``service`` (not yet running); ``started(port)`` is called once it listens."""
    config = uvicorn.Config(make_app(service, settings), host=settings.host, port=settings.port, log_level="warning",
                            access_log=False, lifespan="on", timeout_graceful_shutdown=DRAIN_S, server_header=False,
                            proxy_headers=False)
    return _Server(config, started)


def serve(service: Service, settings: ServeSettings, started: Callable[[int], None] | None = None) -> dict[str, int]:
    """Serve until stopped (SIGTERM, SIGINT); what was served: frames answered and refused, sessions created.
    A port already taken is an :class:`OSError` raised before serving; ``started(port)`` once it listens."""
    sock = listen(settings.host, settings.port)
    server = build_server(service, settings, started)
    old = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_S)
    try:
        with sock:
            server.run(sockets=[sock])
    finally:
        sys.setswitchinterval(old)
    api = server.config.app.state.api
    return {"frames": api.metrics.frames["ok"], "refused": api.metrics.frames["refused"],
            "sessions": api.sessions.created}
