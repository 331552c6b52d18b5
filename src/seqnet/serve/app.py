"""The ASGI app (Starlette): routes, the token, errors as JSON, frames off the event loop.

=======  ==========================  ====================================================================
GET      /health                     ``{"status": "ok", "map": NAME, "frames": N}`` (no token)
GET      /                           the live page (:mod:`.page`; holds no data, no token)
GET      /v1/state                   what the page draws: the route, each session's latest answers
GET      /metrics                    Prometheus text (:mod:`.metrics`)
POST     /v1/sessions                201 ``{"session": ID}`` (429 when the server holds its most)
DELETE   /v1/sessions/ID             204
POST     /v1/sessions/ID/frames      200: the answer of :meth:`Service.answer <.service.Service.answer>`
=======  ==========================  ====================================================================

Every refusal is ``{"error": "..."}`` with 400, 401, 404, 405, 413, 415 or 429 (:class:`.errors.HttpError`); an
unexpected failure is logged and answered 500 ``{"error": "internal error"}`` without its details. A session's
frames are localised in arrival order (its lock, taken as a frame's headers arrive) on a pool of
``settings.workers`` threads, so the event loop keeps answering other sessions.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import time
from collections.abc import AsyncIterator, Awaitable, Callable

import anyio
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route

from ..core.errors import SeqnetError
from ..core.log import logger
from ..localize.localizer import Estimate
from . import page
from .bodies import content_type, read_limited
from .errors import BAD_REQUEST, UNAUTHORIZED, HttpError
from .metrics import CONTENT_TYPE, Metrics
from .service import Service
from .sessions import Session, Sessions
from .settings import ServeSettings

Handler = Callable[[Request], Awaitable[Response]]


def error_response(status: int, message: str) -> JSONResponse:
    headers = {"WWW-Authenticate": "Bearer"} if status == UNAUTHORIZED else None
    return JSONResponse({"error": message}, status_code=status, headers=headers)


class Api:
    """The routes over one :class:`Service` (shared map) and its :class:`Sessions`."""

    def __init__(self, service: Service, settings: ServeSettings) -> None:
        self.service, self.settings = service, settings
        self.sessions = Sessions(settings.max_sessions, settings.session_idle_s)
        self.metrics = Metrics()
        self.route = service.route()
        self.token = None if settings.token is None else settings.token.encode()
        self.limiter: anyio.CapacityLimiter | None = None

    def authorise(self, request: Request) -> None:
        """401 unless ``Authorization: Bearer TOKEN`` carries the token (compared in constant time)."""
        if self.token is None:
            return
        scheme, _, given = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), self.token):
            raise HttpError(UNAUTHORIZED, "missing or wrong token: send Authorization: Bearer TOKEN")

    async def off_loop(self, fn: Callable, *args: object) -> object:
        """``fn(*args)`` on the worker threads."""
        return await anyio.to_thread.run_sync(fn, *args, limiter=self.limiter)

    async def health(self, request: Request) -> Response:
        return JSONResponse({"status": "ok", "map": self.service.name, "frames": self.service.frames})

    async def page(self, request: Request) -> Response:
        return HTMLResponse(page.PAGE, headers=page.HEADERS)

    async def state(self, request: Request) -> Response:
        self.authorise(request)
        return JSONResponse({"map": self.service.name, "frames": self.service.frames, "route": self.route,
                             "sessions": self.sessions.views()}, headers={"Cache-Control": "no-store"})

    async def prometheus(self, request: Request) -> Response:
        self.authorise(request)
        s = self.sessions
        return Response(self.metrics.render(len(s), s.created, s.expired), media_type=CONTENT_TYPE)

    async def create(self, request: Request) -> Response:
        self.authorise(request)
        self.sessions.check_room()
        session = self.sessions.add(await self.off_loop(self.service.localizer))
        logger.debug("serve: session %s… created", session.id[:6])
        return JSONResponse({"session": session.id}, status_code=201)

    async def delete(self, request: Request) -> Response:
        self.authorise(request)
        self.sessions.delete(request.path_params["sid"])
        return Response(status_code=204)

    async def frame(self, request: Request) -> Response:
        self.authorise(request)
        try:
            session = self.sessions.get(request.path_params["sid"])
            kind = content_type(request.headers.get("content-type"))
            async with session.lock:  # frames of one session: one at a time, in arrival order
                body = await read_limited(request.stream(), request.headers.get("content-length"),
                                          self.settings.max_body)
                t0 = time.perf_counter()
                est = await self.off_loop(self.localize, session, body, kind)
                spent = time.perf_counter() - t0
                answer = self.service.answer(est, spent * 1e3)
                session.recent.append(answer)
                session.used = self.sessions.clock()
        except HttpError:
            self.metrics.refused()
            raise
        except SeqnetError as e:  # what the localiser refuses (NaN, inf): this frame only, its window untouched
            self.metrics.refused()
            raise HttpError(BAD_REQUEST, str(e)) from e
        self.metrics.answered(spent)
        return JSONResponse(answer)

    def localize(self, session: Session, body: bytes, kind: str) -> Estimate:
        """On a worker thread: the body's descriptor (an image described) through the session's localiser."""
        return session.localizer.step(self.service.frame(body, kind))

    def guarded(self, handler: Handler) -> Handler:
        """``handler`` with every refusal as JSON and every status counted."""

        async def run(request: Request) -> Response:
            try:
                response = await handler(request)
            except HttpError as e:
                response = error_response(e.status, e.message)
            except Exception as e:  # noqa: BLE001 - the last resort: logged here, never shown to the client
                logger.error("serve: %s %s failed: %s: %s", request.method, request.url.path, type(e).__name__,
                             " ".join(str(e).split())[:300], exc_info=logger.isEnabledFor(10))
                response = error_response(500, "internal error")
            self.metrics.request(response.status_code)
            return response

        return run

    async def expiry(self) -> None:
        """Expire idle sessions, a few times per idle period."""
        interval = min(max(self.settings.session_idle_s / 4, 0.05), 10.0)
        while True:
            await asyncio.sleep(interval)
            for sid in self.sessions.expire():
                logger.debug("serve: session %s… expired", sid[:6])


def make_app(service: Service, settings: ServeSettings) -> Starlette:
    """The ASGI app serving ``service`` with ``settings`` (the routes of the module docstring)."""
    api = Api(service, settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        api.limiter = anyio.CapacityLimiter(settings.workers)
        task = asyncio.get_running_loop().create_task(api.expiry())
        try:
            yield
        finally:
            task.cancel()

    async def http_error(request: Request, exc: Exception) -> Response:
        status = exc.status_code if isinstance(exc, HTTPException) else 500
        api.metrics.request(status)
        return error_response(status, {404: "no such route", 405: "method not allowed"}.get(status, "error"))

    g = api.guarded
    routes = [Route("/health", g(api.health), methods=["GET"]), Route("/", g(api.page), methods=["GET"]),
              Route("/v1/state", g(api.state), methods=["GET"]), Route("/metrics", g(api.prometheus), methods=["GET"]),
              Route("/v1/sessions", g(api.create), methods=["POST"]),
              Route("/v1/sessions/{sid}", g(api.delete), methods=["DELETE"]),
              Route("/v1/sessions/{sid}/frames", g(api.frame), methods=["POST"])]
    app = Starlette(routes=routes, lifespan=lifespan, exception_handlers={HTTPException: http_error})
    app.state.api = api
    return app
