"""The studio's HTTP routes (starlette): the page, its JSON API over a :class:`Studio`
(core.py), previews, live views' data and modules, and the websocket (live.py).

Imported when the server starts (it needs the studio extra).
"""
from __future__ import annotations

from pathlib import Path

from starlette.concurrency import run_in_threadpool
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles

from ..errors import GraphkitError
from .live import LiveSocket, changes_shape, live_view, loopback
from .views import NotReady, view_for

STATIC = Path(__file__).resolve().parent / "static"


def routes(studio, token: str, cookie: str) -> list:
    api = Api(studio, token, cookie)
    return [
        Route("/", api.index),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/api/state", api.state),
        Route("/api/params", api.params, methods=["POST"]),
        Route("/api/run", api.run, methods=["POST"]),
        Route("/api/stop", api.stop, methods=["POST"]),
        Route("/api/autorun", api.autorun, methods=["POST"]),
        Route("/api/save", api.save, methods=["POST"]),
        Route("/api/nodes", api.nodes),
        Route("/api/edit", api.edit, methods=["POST"]),
        Route("/api/undo", api.undo, methods=["POST"]),
        Route("/api/redo", api.redo, methods=["POST"]),
        Route("/api/preview", api.preview),
        Route("/api/manifest", api.manifest),
        Route("/api/view/{node}", api.view_data),
        Route("/views/{type}.js", api.view_js),
        WebSocketRoute("/ws", LiveSocket.endpoint(studio)),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]


def node_catalogue(registry) -> list[dict]:
    """`graphkit nodes --json`'s rows (the palette), a node type that cannot load left out."""
    from ..nodeinfo import node_info

    rows = []
    for n in registry.node_names():
        try:
            rows.append(node_info(registry, n))
        except GraphkitError:
            continue
    return rows


def err(status: int, message: str, **extra) -> JSONResponse:
    return JSONResponse({"ok": False, "error": message, **extra}, status_code=status)


async def body(request) -> dict:
    """The request's JSON object ({} when it is not one)."""
    try:
        data = await request.json()
    except (ValueError, UnicodeDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


class Api:
    """The route handlers."""

    def __init__(self, studio, token: str, cookie: str):
        self.studio, self.token, self.cookie = studio, token, cookie
        self._palette = None

    async def index(self, request):
        r = FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})
        r.set_cookie(self.cookie, self.token, httponly=True, samesite="strict", path="/")
        return r

    async def state(self, request):
        return JSONResponse(await run_in_threadpool(self.studio.state))

    async def params(self, request):
        changes = (await body(request)).get("changes")
        if not changes_shape(changes):
            return err(400, "expected {\"changes\": [{\"node\": NAME or null, \"param\": NAME, \"value\": V}]}")
        res = await run_in_threadpool(self.studio.set_params, changes)
        return JSONResponse(res, status_code=200 if res.get("ok") else 422)

    async def run(self, request):
        if self.studio.graph is None:
            return err(422, "the graph does not validate", errors=self.studio.errors)
        return JSONResponse({"ok": True, "gen": self.studio.request_run()})

    async def stop(self, request):
        self.studio.stop()
        return JSONResponse({"ok": True})

    async def autorun(self, request):
        data = await body(request)
        self.studio.set_autorun(bool(data.get("on", True)))
        return JSONResponse({"ok": True, "autorun": self.studio.autorun})

    async def save(self, request):
        path = (await body(request)).get("path")
        if not isinstance(path, str) or not path.strip():
            return err(400, "expected {\"path\": \"file.yaml\"}")
        try:
            written = await run_in_threadpool(self.studio.save_as, path.strip())
        except GraphkitError as e:
            return err(422, str(e))
        return JSONResponse({"ok": True, "path": written})

    async def nodes(self, request):
        """The palette: what `graphkit nodes --json` says of every registered node type."""
        if self._palette is None:
            self._palette = await run_in_threadpool(node_catalogue, self.studio.registry)
        return JSONResponse(self._palette)

    async def edit(self, request):
        edits = (await body(request)).get("edits")
        if not isinstance(edits, list) or not all(isinstance(e, dict) for e in edits):
            return err(400, "expected {\"edits\": [{\"op\": ..., ...}]}")
        res = await run_in_threadpool(self.studio.edit, edits)
        return JSONResponse(res, status_code=200 if res["ok"] else 422)

    async def undo(self, request):
        return JSONResponse(await run_in_threadpool(self.studio.undo))

    async def redo(self, request):
        return JSONResponse(await run_in_threadpool(self.studio.undo, True))

    async def preview(self, request):
        q = request.query_params
        node, port = q.get("node", ""), q.get("port", "")
        try:
            exposure = float(q.get("exposure", "0") or 0)
            max_side = int(q.get("max", "0") or 0)
        except ValueError:
            return err(400, "exposure and max must be numbers")
        try:
            # on the loopback bytes cost nothing: an uncompressed PNG (encodes ~10× faster)
            level = 0 if loopback(request) else 1
            data = await run_in_threadpool(self.studio.preview, node, port, exposure, max_side, level)
        except GraphkitError as e:
            return err(404, str(e))
        if data is None:
            return err(404, f"{node}.{port} has no value yet")
        if data == b"":
            return err(415, f"{node}.{port} is not an image")
        return Response(data, media_type="image/png", headers={"cache-control": "private, max-age=3600"})

    async def manifest(self, request):
        return JSONResponse(self.studio.manifest or {})

    async def view_data(self, request):
        name = request.path_params["node"]
        v = live_view(self.studio, name)
        if v is None:
            return err(404, f"node '{name}' has no live view")
        try:
            data = await run_in_threadpool(v.data)
        except NotReady as e:  # not an error: the page mounts the view when the run is done
            return JSONResponse({"ok": False, "pending": True, "error": str(e)})
        except GraphkitError as e:
            return err(409, str(e))
        return JSONResponse({"ok": True, "node": name, "data": data, **v.describe()})

    async def view_js(self, request):
        typ = request.path_params["type"]
        cls = view_for(self.studio.registry, typ)
        if cls is None or not cls.js or not cls.js_path().is_file():
            return err(404, f"node type '{typ}' has no live view module")
        return FileResponse(cls.js_path(), media_type="text/javascript", headers={"cache-control": "no-store"})
