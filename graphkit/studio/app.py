"""The studio's web server: starlette routes and a websocket over a :class:`Studio`, served
by uvicorn on 127.0.0.1 (unless told otherwise) with a random per-run token.

Every request must carry the token: in the URL (``?token=``), in an ``X-Graphkit-Token``
header, or in the cookie that the page sets when it is opened with the token (HttpOnly,
SameSite=Strict, so another web page cannot send it); anything else gets 403.
"""
from __future__ import annotations

import asyncio
import collections
import contextlib
import hmac
import json
import secrets
import socket
import struct
import sys
from http.cookies import SimpleCookie
from pathlib import Path
from urllib.parse import parse_qs

from ..errors import GraphkitError, UsageError

STATIC = Path(__file__).resolve().parent / "static"


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


def _changes_shape(changes) -> bool:
    """A param-change list as the page sends it (POST /api/params or over the websocket):
    [{node, param, value}] with ``param`` a name (set_params checks the rest)."""
    return isinstance(changes, list) and all(isinstance(c, dict) and isinstance(c.get("param"), str)
                                             for c in changes)


def build_app(studio, token: str, cookie: str = "graphkit_token"):
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route, WebSocketRoute
    from starlette.staticfiles import StaticFiles
    from starlette.websockets import WebSocket, WebSocketDisconnect

    from .views import NotReady, view_for

    def err(status: int, message: str, **extra):
        return JSONResponse({"ok": False, "error": message, **extra}, status_code=status)

    async def index(request):
        r = FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})
        r.set_cookie(cookie, token, httponly=True, samesite="strict", path="/")
        return r

    async def state(request):
        return JSONResponse(await run_in_threadpool(studio.state))

    async def body(request) -> dict:
        try:
            data = await request.json()
        except (ValueError, UnicodeDecodeError):
            return {}
        return data if isinstance(data, dict) else {}

    async def params(request):
        data = await body(request)
        changes = data.get("changes")
        if not _changes_shape(changes):
            return err(400, "expected {\"changes\": [{\"node\": NAME or null, \"param\": NAME, \"value\": V}]}")
        res = await run_in_threadpool(studio.set_params, changes)
        return JSONResponse(res, status_code=200 if res.get("ok") else 422)

    async def run(request):
        if studio.graph is None:
            return err(422, "the graph does not validate", errors=studio.errors)
        return JSONResponse({"ok": True, "gen": studio.request_run()})

    async def autorun(request):
        data = await body(request)
        studio.set_autorun(bool(data.get("on", True)))
        return JSONResponse({"ok": True, "autorun": studio.autorun})

    async def save(request):
        data = await body(request)
        path = data.get("path")
        if not isinstance(path, str) or not path.strip():
            return err(400, "expected {\"path\": \"file.yaml\"}")
        try:
            written = await run_in_threadpool(studio.save_as, path.strip())
        except GraphkitError as e:
            return err(422, str(e))
        return JSONResponse({"ok": True, "path": written})

    async def preview(request):
        q = request.query_params
        node, port = q.get("node", ""), q.get("port", "")
        try:
            exposure = float(q.get("exposure", "0") or 0)
            max_side = int(q.get("max", "0") or 0)
        except ValueError:
            return err(400, "exposure and max must be numbers")

        try:
            # on the loopback bytes cost nothing: an uncompressed PNG (encodes ~10× faster)
            level = 0 if _loopback(request) else 1
            data = await run_in_threadpool(studio.preview, node, port, exposure, max_side, level)
        except GraphkitError as e:
            return err(404, str(e))
        if data is None:
            return err(404, f"{node}.{port} has no value yet")
        if data == b"":
            return err(415, f"{node}.{port} is not an image")
        return Response(data, media_type="image/png", headers={"cache-control": "private, max-age=3600"})

    async def manifest(request):
        return JSONResponse(studio.manifest or {})

    def live_view(name: str):
        g = studio.graph
        if g is None or name not in g.nodes:
            return None
        cls = view_for(studio.registry, g.nodes[name].type)
        return cls(studio, name) if cls else None

    async def view_data(request):
        name = request.path_params["node"]
        v = live_view(name)
        if v is None:
            return err(404, f"node '{name}' has no live view")
        try:
            data = await run_in_threadpool(v.data)
        except NotReady as e:  # not an error: the page mounts the view when the run is done
            return JSONResponse({"ok": False, "pending": True, "error": str(e)})
        except GraphkitError as e:
            return err(409, str(e))
        return JSONResponse({"ok": True, "node": name, "data": data, **v.describe()})

    async def view_js(request):
        typ = request.path_params["type"]
        cls = view_for(studio.registry, typ)
        if cls is None or not cls.js or not cls.js_path().is_file():
            return err(404, f"node type '{typ}' has no live view module")
        return FileResponse(cls.js_path(), media_type="text/javascript", headers={"cache-control": "no-store"})

    async def ws(websocket: WebSocket):
        await websocket.accept()
        local = _loopback(websocket)
        loop = asyncio.get_running_loop()
        # the run's events, in order; the loop is woken once per burst (not once per event)
        # and sends the events queued meanwhile as one message, so a run's stream of node
        # events competes less with the run and the page for the CPU
        pending: collections.deque = collections.deque()
        ready = asyncio.Event()
        woken = [False]

        def wake():
            woken[0] = False
            ready.set()

        def on_event(ev):
            pending.append(ev)
            if not woken[0]:
                woken[0] = True
                loop.call_soon_threadsafe(wake)

        unsubscribe = studio.subscribe(on_event)
        views: dict[str, object] = {}

        async def pump():
            while True:
                await ready.wait()
                ready.clear()
                batch = []
                while pending:
                    ev = pending.popleft()
                    if ev.get("type") != "preview":
                        batch.append(ev)
                        continue
                    if (ev["level"] == 0) != local:
                        continue  # encoded for the other kind of page
                    if batch:  # what came before it goes first
                        await _send_events(batch)
                        batch = []
                    # a preview on show, computed anew: the PNG itself; the page answers
                    # "shown" (studio.served) once it shows it or passes
                    head = json.dumps({k: v for k, v in ev.items() if k != "data"}).encode()
                    await websocket.send_bytes(struct.pack("<I", len(head)) + head + ev["data"])
                if batch:
                    await _send_events(batch)

        async def _send_events(batch):
            if len(batch) == 1:
                await websocket.send_text(json.dumps(batch[0], default=str))
            else:
                await websocket.send_text(json.dumps({"type": "batch", "events": batch}, default=str))

        async def params_msg(msg):
            """A param change over the socket (the page's sliders): as POST /api/params,
            without an HTTP request per move; the answer carries the message's id."""
            changes = msg.get("changes")
            if not _changes_shape(changes):
                res = {"ok": False, "errors": [{"text": "expected changes: [{node, param, value}]"}]}
            else:
                res = await run_in_threadpool(studio.set_params, changes)
            await websocket.send_text(json.dumps({"type": "params", "id": msg.get("id"), **res}, default=str))

        async def frame(msg):
            name = msg.get("node", "")
            v = views.get(name) or live_view(name)
            head = {"type": "frame", "node": name, "id": msg.get("id")}
            if v is None:
                head["error"] = f"node '{name}' has no live view"
                return await websocket.send_text(json.dumps(head))
            views[name] = v
            try:
                out = await run_in_threadpool(_frame_bytes, v, msg.get("values") or {},
                                              float(msg.get("exposure", 0) or 0), 0 if local else 1)
            except GraphkitError as e:
                head["error"] = str(e)
                return await websocket.send_text(json.dumps(head))
            info, png = out
            h = json.dumps({**head, **info}).encode()
            await websocket.send_bytes(struct.pack("<I", len(h)) + h + png)

        async def commit(msg):
            name = msg.get("node", "")
            v = views.get(name) or live_view(name)
            if v is None:
                return
            try:
                changes = await run_in_threadpool(v.commit, msg.get("values") or {})
            except GraphkitError as e:
                return await websocket.send_text(json.dumps({"type": "commit", "node": name, "ok": False,
                                                             "errors": [{"text": str(e)}]}))
            res = await run_in_threadpool(studio.set_params, changes) if changes else {"ok": True}
            views.pop(name, None)
            await websocket.send_text(json.dumps({"type": "commit", "node": name, **res}))

        sender = None
        try:
            # the snapshot first; events queued meanwhile follow it (they are newer than it)
            await websocket.send_text(json.dumps({"type": "state", "state": await run_in_threadpool(studio.state)}))
            sender = asyncio.create_task(pump())
            while True:
                msg = await websocket.receive_text()
                try:
                    msg = json.loads(msg)
                except ValueError:
                    continue
                if not isinstance(msg, dict):
                    continue
                if msg.get("type") == "params":
                    await params_msg(msg)
                elif msg.get("type") == "frame":
                    await frame(msg)
                elif msg.get("type") == "commit":
                    await commit(msg)
                elif msg.get("type") == "shown" and isinstance(msg.get("digest"), str):
                    studio.served(msg["digest"])
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            unsubscribe()
            if sender is not None:
                sender.cancel()

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        await run_in_threadpool(studio.close)

    routes = [
        Route("/", index),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/api/state", state),
        Route("/api/params", params, methods=["POST"]),
        Route("/api/run", run, methods=["POST"]),
        Route("/api/autorun", autorun, methods=["POST"]),
        Route("/api/save", save, methods=["POST"]),
        Route("/api/preview", preview),
        Route("/api/manifest", manifest),
        Route("/api/view/{node}", view_data),
        Route("/views/{type}.js", view_js),
        WebSocketRoute("/ws", ws),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    return TokenGate(app, token, cookie)


def _loopback(request) -> bool:
    import ipaddress

    host = request.client.host if request.client else ""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _frame_bytes(view, values: dict, exposure: float, level: int = 1):
    import time

    import numpy as np

    from ..types import Image
    from .imaging import png, display_rgb

    t0 = time.perf_counter()
    out = view.frame(values)
    info = {}
    if isinstance(out, dict):
        info = {k: v for k, v in out.items() if k != "image"}
        out = out.get("image")
    px = out.pixels if isinstance(out, Image) else np.asarray(out)
    t1 = time.perf_counter()
    data = png(display_rgb(px, exposure), level)
    info.update(compute_ms=round((t1 - t0) * 1e3, 2), encode_ms=round((time.perf_counter() - t1) * 1e3, 2),
                width=int(px.shape[1]), height=int(px.shape[0]))
    return info, data


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
    from .core import Studio

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
