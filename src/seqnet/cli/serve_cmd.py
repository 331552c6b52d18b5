"""``seqnet serve``: the online localiser as an HTTP service (docs/serve.md). The server's dependencies
(``seqnet[serve]``: starlette, uvicorn) are imported only when it runs."""

from __future__ import annotations

import argparse
import os
import sys

from ..security.text import shown
from . import COMMANDS
from .common import check_method_options, positive_float, positive_int
from .localize_cmd import add_localizer_options, localizer_config

_WORKERS = max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


def register(sub: argparse._SubParsersAction) -> None:
    from ..serve.settings import TOKEN_ENV, ServeSettings

    d = ServeSettings(no_auth=True)
    p = sub.add_parser("serve", help=COMMANDS["serve"],
                       description="Serve the online localiser over HTTP: one map loaded once, one causal window per "
                       "session, each session's answers those of `seqnet localize` on the same frames in order. "
                       f"Needs a token (--token-file or {TOKEN_ENV}) unless --no-auth on 127.0.0.1; needs "
                       "seqnet[serve]. API, errors and TLS behind a reverse proxy: docs/serve.md.")
    p.add_argument("--map", required=True, once_hint="one server serves one map: run a second server (another "
                   "--port) for another map", help="the map: an index map (seqnet index build --window causal) or a "
                   "seqnet dataset directory, whose reference traverse is used (as seqnet localize --map)")
    p.add_argument("--host", default=d.host, help=f"address to listen on (default {d.host}; put TLS in front: "
                   "docs/serve.md)")
    p.add_argument("--port", type=int, default=d.port, help=f"port (default {d.port}; 0: a free one)")
    p.add_argument("--token-file", metavar="FILE", help=f"file holding the token clients send as Authorization: "
                   f"Bearer TOKEN (default: ${TOKEN_ENV}; an empty token is no token)")
    p.add_argument("--no-auth", action="store_true", help="serve without a token: on 127.0.0.1 (or ::1) only")
    p.add_argument("--max-sessions", type=positive_int, default=d.max_sessions,
                   help=f"sessions held at once; more are refused with 429 (default {d.max_sessions})")
    p.add_argument("--session-idle-s", type=positive_float, default=d.session_idle_s, metavar="S",
                   help=f"a session unused for S seconds expires (default {d.session_idle_s:g})")
    p.add_argument("--max-body-mb", type=positive_float, default=d.max_body_mb, metavar="MB",
                   help=f"largest request body; larger ones are refused with 413 (default {d.max_body_mb:g})")
    p.add_argument("--workers", type=positive_int, default=_WORKERS, help="frames localised at once, on threads "
                   f"(default {_WORKERS}: the CPUs this process may use, at most 4)")
    add_localizer_options(p)
    p.set_defaults(func=run, default_threads=1, distances=None)  # a frame is little work: one thread each


def run(args: argparse.Namespace) -> int:
    from ..serve.settings import ServeSettings, check_installed, read_token

    check_installed()
    settings = ServeSettings(host=args.host, port=args.port, token=read_token(args.token_file),
                             no_auth=args.no_auth, max_sessions=args.max_sessions,
                             session_idle_s=args.session_idle_s, max_body_mb=args.max_body_mb, workers=args.workers)
    conf = localizer_config(args)
    check_method_options(args, [args.method])
    from ..serve.server import serve
    from ..serve.service import load_service

    service = load_service(conf, args.map, args.model, args.shortlist_model, args.rerank_model, args.describer)

    def started(port: int) -> None:
        host = f"[{settings.host}]" if ":" in settings.host else settings.host
        images = "descriptors and images" if service.describer is not None else "descriptors"
        print(f"serving {service.name} ({service.frames} frames, {conf.method}; {images}) on http://{host}:{port}/"
              f"{'' if settings.token is None else ' (token required)'}; stop with SIGTERM or Ctrl-C", flush=True)
        if args.settings_line:  # the map's K chosen on val, or the --top-k that won over it: after the address
            print(shown(args.settings_line), flush=True)  # line, which tools read first

    stats = serve(service, settings, started)
    print(f"stopped: {stats['frames']} frames answered ({stats['refused']} refused), {stats['sessions']} sessions")
    sys.stdout.flush()
    return 0
