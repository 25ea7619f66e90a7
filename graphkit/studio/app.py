"""The studio's web server: the routes (routes.py) and the websocket (live.py) over a
:class:`Studio` (core.py), served by uvicorn on 127.0.0.1 (unless told otherwise) with a
random per-run token.

Every request must carry the token: in the URL (``?token=``), in an ``X-Graphkit-Token``
header, or in the cookie that the page sets when it is opened with the token (HttpOnly,
SameSite=Strict, so another web page cannot send it); anything else gets 403.
"""
from __future__ import annotations

import contextlib
import hmac
import secrets
import socket
import sys
from http.cookies import SimpleCookie
from urllib.parse import parse_qs

from ..errors import UsageError


class TokenGate:
    """ASGI middleware: 403 (or websocket close 1008) without the run's token."""

    def __init__(self, app, token: str, cookie: str):
        self.app, self.token, self.cookie = app, token, cookie

    def _ok(self, scope) -> bool:
        q = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        cands = q.get("token", [])
        cookies = SimpleCookie()
        for k, v in scope.get("headers", []):
            if k == b"x-graphkit-token":
                cands.append(v.decode("latin-1"))
            elif k == b"cookie":
                with contextlib.suppress(Exception):
                    cookies.load(v.decode("latin-1"))
        if self.cookie in cookies:
            cands.append(cookies[self.cookie].value)
        return any(hmac.compare_digest(c.encode(), self.token.encode()) for c in cands)

    def _same_origin(self, scope) -> bool:
        h = dict(scope.get("headers", []))
        origin, host = h.get(b"origin"), h.get(b"host")
        if origin is None:
            return True
        return origin.split(b"://", 1)[-1] == host

    async def __call__(self, scope, receive, send):
        if scope["type"] == "lifespan":
            return await self.app(scope, receive, send)
        ok = self._ok(scope) and (scope["type"] != "websocket" or self._same_origin(scope))
        if ok:
            return await self.app(scope, receive, send)
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": "token required"})
            return
        body = b"403: this studio needs the token from the URL it printed\n"
        await send({"type": "http.response.start", "status": 403,
                    "headers": [(b"content-type", b"text/plain; charset=utf-8"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


def build_app(studio, token: str, cookie: str = "graphkit_token"):
    """The ASGI app: the routes (routes.py) behind the token gate; closing it closes the studio."""
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool

    from .routes import routes

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        await run_in_threadpool(studio.close)

    return TokenGate(Starlette(routes=routes(studio, token, cookie), lifespan=lifespan), token, cookie)


def serve(graph: str, *, host: str = "127.0.0.1", port: int = 0, cache: str = ".graphkit-cache",
          out: str | None = None, backends: list[str] | None = None, jobs: int = 1,
          autorun: bool = True, registry=None, token: str | None = None, open_browser: bool = False,
          stream=None) -> int:
    """Run the studio for ``graph`` until interrupted (Ctrl-C); prints the URL first."""
    try:
        import uvicorn
    except ImportError:
        raise UsageError("the studio needs its extra: pip install 'relightkit[studio]' "
                         "(starlette, uvicorn, websockets)") from None
    from ..memory import tune_malloc
    from .core import Studio

    tune_malloc()  # also when the studio is started from Python rather than `graphkit serve`
    stream = stream or sys.stdout
    token = token or secrets.token_urlsafe(24)
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(128)  # connections wait in the backlog until uvicorn accepts them
    except OSError as e:
        sock.close()
        raise UsageError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
    studio = Studio(graph, cache=cache, out=out, registry=registry, backends=backends, jobs=jobs,
                    autorun=autorun, freeze_gc=True)
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{bound}/?token={token}"
    app = build_app(studio, token, cookie=f"graphkit_token_{bound}")
    # no permessage-deflate: zlib over each pushed preview (1 MB of RGBA, or a PNG that is
    # compressed already) cost ~40-60 ms of the server's CPU per slider move on these cores
    config = uvicorn.Config(app, log_level="warning", ws="websockets-sansio", lifespan="on",
                            timeout_graceful_shutdown=2, access_log=False, ws_per_message_deflate=False)
    server = uvicorn.Server(config)
    if studio.errors:
        for e in studio.errors:
            print(e["text"], file=sys.stderr)
        print("graphkit: the graph does not validate; the studio shows its errors and runs nothing",
              file=sys.stderr)
    print(f"graphkit studio: {url}", file=stream, flush=True)
    if host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: listening on {host}: anyone who can reach it and has the URL can drive this studio",
              file=sys.stderr)
    if open_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        server.run(sockets=[sock])  # uvicorn re-raises Ctrl-C once it has shut down
    except KeyboardInterrupt:
        pass
    finally:
        studio.close()
        sock.close()
    print("graphkit studio: stopped", file=sys.stderr)
    return 0
