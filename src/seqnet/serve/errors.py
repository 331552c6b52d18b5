"""The one error a request can end in: an HTTP status and a one-line message, answered as ``{"error": ...}``."""

from __future__ import annotations

from ..core.errors import SeqnetError

BAD_REQUEST, UNAUTHORIZED, NOT_FOUND, TOO_LARGE, UNSUPPORTED, TOO_MANY = 400, 401, 404, 413, 415, 429


class HttpError(SeqnetError):
    """A refused request: ``status`` and the message sent back (never a traceback)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = int(status)
        self.message = " ".join(str(message).split())[:500]
