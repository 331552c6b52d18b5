"""``seqnet serve``: the online localiser as an HTTP service (docs/serve.md).

One map is loaded once and shared; every session is its own :class:`~seqnet.localize.localizer.Localizer`
(its own causal window), so a session's answers equal ``seqnet localize`` on the same frames in order. The
package only adapts HTTP to the localiser: :mod:`.service` (the map, the describer, one answer as JSON),
:mod:`.bodies` (request bodies: descriptors and images, read through :mod:`seqnet.security`), :mod:`.sessions`,
:mod:`.metrics` (Prometheus text), :mod:`.page` (the live page), :mod:`.app` (the ASGI app: routes, auth, errors),
:mod:`.errors` (the refusal: a status and a message), :mod:`.settings` (settings and token, checked before the map is
read) and :mod:`.server` (uvicorn: listen, drain on SIGTERM). Its dependencies (starlette, uvicorn) are the
``serve`` extra and are imported only by :mod:`.app` and :mod:`.server`.
"""
