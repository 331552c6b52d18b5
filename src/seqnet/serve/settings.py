"""The server's settings and its token: refused at start-up, before the map is loaded, when they are unsafe."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path

from ..core.config import Config, check_bool, check_float, check_int
from ..core.errors import ConfigError
from ..core.log import logger
from ..security.inputs import read_bytes

TOKEN_ENV = "SEQNET_TOKEN"
LOOPBACK = ("127.0.0.1", "::1")  # --no-auth binds only here
MAX_TOKEN_BYTES = 4096
SHORT_TOKEN = 16  # a shorter token is accepted with a warning


@dataclasses.dataclass(frozen=True)
class ServeSettings(Config):
    """Settings of ``seqnet serve``.

    Attributes:
        host, port: where it listens; token: what ``Authorization: Bearer`` must carry (None: no auth, which only
            ``no_auth`` on a loopback address allows).
        max_sessions: sessions held at once (more: 429); session_idle_s: a session unused this long expires.
        max_body_mb: the largest request body (more: 413); workers: frames localised at once (threads).
    """

    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = dataclasses.field(default=None, repr=False)
    no_auth: bool = False
    max_sessions: int = 64
    session_idle_s: float = 300.0
    max_body_mb: float = 8.0
    workers: int = 2

    def __post_init__(self) -> None:
        self._set("port", check_int("port", self.port, 0, 65535))
        self._set("no_auth", check_bool("no_auth", self.no_auth))
        self._set("max_sessions", check_int("max_sessions", self.max_sessions, 1))
        self._set("session_idle_s", check_float("session_idle_s", self.session_idle_s, 0.0, strict=True))
        self._set("max_body_mb", check_float("max_body_mb", self.max_body_mb, 0.0, strict=True))
        self._set("workers", check_int("workers", self.workers, 1))
        if self.no_auth and self.token is not None:
            raise ConfigError("--no-auth and a token (--token-file or SEQNET_TOKEN) contradict each other; drop one")
        if self.no_auth and self.host not in LOOPBACK:
            raise ConfigError(f"--no-auth serves on {' or '.join(LOOPBACK)} only, not {self.host!r}: anyone who can "
                              "reach the address could use the map; give a token (--token-file or SEQNET_TOKEN)")
        if self.token is None and not self.no_auth:
            raise ConfigError("seqnet serve refuses to start without a token: put one in a file (--token-file) or in "
                              f"{TOKEN_ENV} (an empty token is no token), or pass --no-auth to serve on 127.0.0.1 "
                              "without one")

    @property
    def max_body(self) -> int:
        """The largest request body in bytes."""
        return max(1, int(self.max_body_mb * (1 << 20)))


def read_token(token_file: str | Path | None, environ: Mapping[str, str] = os.environ) -> str | None:
    """The token: the content of ``token_file`` when given, else ``SEQNET_TOKEN``; stripped, and an empty token
    is no token (None). A token must be printable ASCII without spaces (it travels in an HTTP header)."""
    if token_file is not None:
        raw = read_bytes(token_file, MAX_TOKEN_BYTES, "token file", ConfigError)
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError as e:
            raise ConfigError(f"token file {token_file}: the token must be printable ASCII") from e
        where = f"token file {token_file}"
    else:
        text, where = environ.get(TOKEN_ENV, "").strip(), TOKEN_ENV
    if not text:
        return None
    if any(not 33 <= ord(c) <= 126 for c in text):
        raise ConfigError(f"{where}: the token must be one line of printable ASCII without spaces")
    if len(text) < SHORT_TOKEN:
        logger.warning("%s: the token has %d characters; a random one of %d or more is harder to guess (e.g. "
                       "python -c 'import secrets; print(secrets.token_urlsafe(32))')", where, len(text), SHORT_TOKEN)
    return text


def check_installed() -> None:
    """The server's packages (the ``serve`` extra) are importable; else a :class:`ConfigError` with the hint."""
    import importlib.util

    missing = [m for m in ("starlette", "uvicorn", "anyio") if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(f"seqnet serve needs {', '.join(missing)} (hint: pip install 'seqnet[serve]')")
