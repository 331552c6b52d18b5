"""Sessions: one localiser (its own causal window) per client stream, created, found, deleted and expired.

Everything here runs on the server's event loop; a session's frames are localised one at a time in arrival order
(its :attr:`Session.lock`, FIFO), off the loop (:mod:`.app`), so one session's frames never reach another's window.
"""

from __future__ import annotations

import asyncio
import secrets
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ..localize.localizer import Localizer
from .errors import NOT_FOUND, TOO_MANY, HttpError

RECENT = 20  # answers kept per session for the live page


class Session:
    """A client's stream: its localiser, its lock (frames in order), its latest answers and when it was used."""

    def __init__(self, sid: str, localizer: Localizer, now: float) -> None:
        self.id, self.localizer = sid, localizer
        self.lock = asyncio.Lock()
        self.created = self.used = now
        self.recent: deque[dict[str, Any]] = deque(maxlen=RECENT)

    def view(self, now: float) -> dict[str, Any]:
        """The session as the live page shows it."""
        return {"session": self.id, "frames": self.localizer.frame, "idle_s": round(now - self.used, 1),
                "latest": list(self.recent)}


class Sessions:
    """At most ``max_sessions`` sessions; one unused for ``idle_s`` seconds (and not localising) expires."""

    def __init__(self, max_sessions: int, idle_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.max, self.idle_s, self.clock = int(max_sessions), float(idle_s), clock
        self.live: dict[str, Session] = {}
        self.created = self.expired = 0

    def __len__(self) -> int:
        return len(self.live)

    def check_room(self) -> None:
        """429 when the server holds its most sessions (idle ones expired first)."""
        self.expire()
        if len(self.live) >= self.max:
            raise HttpError(TOO_MANY, f"the server holds its most sessions ({self.max}); delete one you no longer "
                            "use, or retry later")

    def add(self, localizer: Localizer) -> Session:
        """A new session around ``localizer`` (:meth:`check_room` first), under an unguessable id."""
        self.check_room()
        sid = secrets.token_urlsafe(16)
        s = self.live[sid] = Session(sid, localizer, self.clock())
        self.created += 1
        return s

    def get(self, sid: str) -> Session:
        """The session ``sid`` (404 when unknown, deleted or expired), marked as used."""
        s = self.live.get(sid)
        if s is None:
            raise HttpError(NOT_FOUND, "unknown session (never created, deleted, or expired after "
                            f"{self.idle_s:g} s idle); create one: POST /v1/sessions")
        s.used = self.clock()
        return s

    def delete(self, sid: str) -> None:
        """Forget ``sid`` (404 when unknown)."""
        self.get(sid)
        del self.live[sid]

    def expire(self) -> list[str]:
        """Drop the sessions idle for longer than ``idle_s`` that are not localising a frame; their ids."""
        now = self.clock()
        gone = [sid for sid, s in self.live.items() if now - s.used > self.idle_s and not s.lock.locked()]
        for sid in gone:
            del self.live[sid]
        self.expired += len(gone)
        return gone

    def views(self) -> list[dict[str, Any]]:
        """Every session as the live page shows it, oldest first."""
        now = self.clock()
        return [s.view(now) for s in self.live.values()]
