"""The studio's live-view protocol: what goes to a page as it happens, and what it sends back.

* :class:`Previews`: the previews a page has on show.  A page's request for a preview marks
  it as on show; when a run computes that node anew, the run encodes it at once (same
  exposure and size) and pushes it to the pages as a ``preview`` event with the image (no
  request round trip), then waits until a page says it has it ("shown") before it goes on
  with the rest of the graph.  A page on the loopback gets raw RGBA (``format: rgba``,
  width × height × 4 bytes) that its canvas takes without decoding; elsewhere the PNG.
* :class:`LiveSocket`: one page's websocket.  Out: the studio's events, queued and sent in
  bursts (one JSON text message per burst, ``{"type": "batch", "events": [...]}`` when there
  are several), and binary messages (a little-endian u32 header length, the JSON header, then
  the image bytes) for pushed previews and live-view frames.  In: ``params`` (a param
  change, as POST /api/params), ``frame`` and ``commit`` (a node's live view, views.py; a
  commit may also save the graph) and
  ``shown`` (a pushed preview reached the page).

The websocket side needs the studio extra (starlette), imported when a page connects.
"""
from __future__ import annotations

import asyncio
import collections
import json
import struct
import threading
import time
from collections import OrderedDict
from typing import Any, Callable

from ..errors import GraphkitError

PREVIEWABLE = ("Image", "Mask")


class Previews:
    """PNGs by (digest, exposure, max side, PNG level), the previews the pages asked for
    lately ((node, port) → {(exposure, max side, level): time}), and the digests a run waits
    to see served before it goes on.  Shares the studio's lock (``wake``'s)."""

    PNG_CACHE = 24  # previews kept (a few exposures / sizes of the outputs on show)
    WATCH_S = 120.0  # a preview the page asked for within this many seconds is "on show"
    HOLD_S = 0.25  # how long a run waits for a page to fetch a new preview on show

    def __init__(self, wake: threading.Condition, emit: Callable[[dict], None],
                 has_pages: Callable[[], bool], memo: dict):
        self._wake, self._emit, self._has_pages, self._memo = wake, emit, has_pages, memo
        self._png: "OrderedDict[tuple, bytes]" = OrderedDict()
        self._watch: dict[tuple[str, str], dict[tuple[float, int, int], float]] = {}
        self._served: set[str] = set()

    def png(self, node: str, port: str, ptype, value, digest: str, exposure: float, max_side: int,
            level: int) -> bytes:
        """The preview of ``node.port`` (``value``, of type ``ptype``) that a page asked for,
        now on show."""
        from .imaging import preview_png

        var = (float(exposure), int(max_side), int(level))
        with self._wake:
            now = time.time()
            seen = self._watch.setdefault((node, port), {})
            for k in [k for k, t in seen.items() if now - t > self.WATCH_S]:
                del seen[k]
            seen[var] = now
            data = self._png.get((digest, *var))
        if data is None:
            data = preview_png(ptype.name, value, *var)
            self._keep((digest, *var), data)
        self.served(digest)
        return data

    def _keep(self, key, data: bytes) -> None:
        with self._wake:
            self._png[key] = data
            self._png.move_to_end(key)
            while len(self._png) > self.PNG_CACHE:
                self._png.popitem(last=False)

    def push(self, graph, name: str, outputs: dict, values: dict | None = None) -> list[str]:
        """Encode and push the previews on show of node ``name``, computed anew with
        ``outputs`` (port → digest; ``values``: port → value, else from memory); their digests."""
        if graph is None or name not in graph.nodes:
            return []
        now = time.time()
        with self._wake:
            if not self._has_pages():
                return []
            todo = self._due(name, outputs, now)
        out = [p for p in (self._encode(graph.nodes[name], item, values) for item in todo) if p]
        with self._wake:
            self._served.difference_update(d for _, d, _, _ in out)
        for port, d, head, data in out:  # pages on show take it from here
            self._emit({"type": "preview", "node": name, "port": port, "digest": d, **head, "data": data})
        return [d for _, d, _, _ in out]

    def _due(self, name: str, outputs: dict, now: float) -> list[tuple]:
        """(port, digest, variant, cache key) of each preview on show of ``name`` not encoded yet."""
        todo = []
        for (node, port), variants in self._watch.items():
            d = outputs.get(port) if node == name else None
            if not isinstance(d, str):
                continue
            for var, t in variants.items():
                key = (d, var[0], var[1], "rgba" if var[2] == 0 else var[2])
                if now - t < self.WATCH_S and key not in self._png:
                    todo.append((port, d, var, key))
        return todo

    def _encode(self, gnode, item: tuple, values: dict | None):
        """(port, digest, header, bytes) of one preview to push (None: nothing to show)."""
        from .imaging import png, preview_rgb, rgba

        port, d, (exposure, max_side, level), key = item
        ptype = gnode.cls.out_ports[port].type
        v = values.get(port) if values else self._memo.get(d)
        if v is None or ptype.name not in PREVIEWABLE:
            return None
        rgb8 = preview_rgb(ptype.name, v, exposure, max_side)
        # a page on the loopback takes raw pixels (no PNG to encode here, none to decode
        # there); elsewhere the PNG (a twentieth of the bytes)
        fmt = "rgba" if level == 0 else "png"
        data = rgba(rgb8) if fmt == "rgba" else png(rgb8, level)
        self._keep(key, data)
        return (port, d, {"exposure": exposure, "max": max_side, "level": level, "format": fmt,
                          "width": int(rgb8.shape[1]), "height": int(rgb8.shape[0])}, data)

    def served(self, digest: str) -> None:
        """A page got the preview of ``digest``."""
        with self._wake:
            self._served.add(digest)
            self._wake.notify_all()

    def await_served(self, digests: list[str], current: Callable[[], bool]) -> None:
        """Wait (at most HOLD_S) until a page has fetched the previews of ``digests``, so
        the rest of the run (file writers, sheets, the --out export) does not compete with
        sending them; ends early once ``current()`` is false (a newer change, closing)."""
        end = time.monotonic() + self.HOLD_S
        with self._wake:
            while not set(digests) <= self._served and current():
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._wake.wait(left)

    def watched_nodes(self, graph) -> list[str]:
        """The node(s) of the preview a page asked for last (and of those asked for with it,
        within 50 ms: its panel's thumbnails): a run computes them, and what they need,
        first, so a slider's preview does not wait for the rest of the graph."""
        with self._wake:
            if not self._has_pages():
                return []
            last = {n: max(seen.values()) for (n, _), seen in self._watch.items() if seen and n in graph.nodes}
        if not last:
            return []
        newest = max(last.values())
        return sorted(n for n, t in last.items() if t >= newest - 0.05 and time.time() - t < self.WATCH_S)

    def keep_only(self, digests: set[str]) -> None:
        """Forget the served digests that are no longer any node's output."""
        with self._wake:
            self._served &= digests


# -- the websocket ---------------------------------------------------------------------------
def changes_shape(changes) -> bool:
    """A param-change list as the page sends it (POST /api/params or over the websocket):
    [{node, param, value}] with ``param`` a name (set_params checks the rest)."""
    return isinstance(changes, list) and all(isinstance(c, dict) and isinstance(c.get("param"), str)
                                             for c in changes)


def loopback(request) -> bool:
    """Whether the page is on this machine (it then gets uncompressed images)."""
    import ipaddress

    host = request.client.host if request.client else ""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def live_view(studio, name: str):
    """The live view of node ``name`` on the studio's graph (None when it has none)."""
    from .views import view_for

    g = studio.graph
    if g is None or name not in g.nodes:
        return None
    cls = view_for(studio.registry, g.nodes[name].type)
    return cls(studio, name) if cls else None


def binary_message(head: dict, data: bytes) -> bytes:
    """A binary websocket message: u32 (little-endian) header length, JSON header, bytes."""
    h = json.dumps(head).encode()
    return struct.pack("<I", len(h)) + h + data


def events_message(batch: list[dict]) -> str:
    if len(batch) == 1:
        return json.dumps(batch[0], default=str)
    return json.dumps({"type": "batch", "events": batch}, default=str)


def frame_bytes(view, values: dict, exposure: float, level: int = 1) -> tuple[dict, bytes]:
    """A live view's frame for ``values``: (its info with timings and size, the PNG)."""
    import numpy as np

    from ..types import Image
    from .imaging import display_rgb, png

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


class LiveSocket:
    """One page's websocket (see the module docstring)."""

    def __init__(self, studio, websocket):
        from starlette.concurrency import run_in_threadpool

        self.studio, self.ws, self._thread = studio, websocket, run_in_threadpool
        self.local = loopback(websocket)
        self.views: dict[str, Any] = {}
        # the run's events, in order; the loop is woken once per burst (not once per event)
        # and sends the events queued meanwhile as one message, so a run's stream of node
        # events competes less with the run and the page for the CPU
        self.pending: collections.deque = collections.deque()
        self.ready = asyncio.Event()
        self.woken = False
        self.loop = asyncio.get_running_loop()

    @classmethod
    def endpoint(cls, studio):
        """The starlette websocket endpoint."""
        async def ws(websocket):
            await websocket.accept()
            await cls(studio, websocket).serve()
        return ws

    def _wake(self):
        self.woken = False
        self.ready.set()

    def _on_event(self, ev: dict) -> None:  # on the run's thread
        self.pending.append(ev)
        if not self.woken:
            self.woken = True
            self.loop.call_soon_threadsafe(self._wake)

    async def serve(self) -> None:
        from starlette.websockets import WebSocketDisconnect

        unsubscribe = self.studio.subscribe(self._on_event)
        sender = None
        try:
            # the snapshot first; events queued meanwhile follow it (they are newer than it)
            state = await self._thread(self.studio.state)
            await self.ws.send_text(json.dumps({"type": "state", "state": state}))
            sender = asyncio.create_task(self._pump())
            while True:
                await self._receive(await self.ws.receive_text())
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            unsubscribe()
            if sender is not None:
                sender.cancel()

    async def _pump(self) -> None:
        while True:
            await self.ready.wait()
            self.ready.clear()
            batch = []
            while self.pending:
                ev = self.pending.popleft()
                if ev.get("type") != "preview":
                    batch.append(ev)
                    continue
                if (ev["level"] == 0) != self.local:
                    continue  # encoded for the other kind of page
                if batch:  # what came before it goes first
                    await self.ws.send_text(events_message(batch))
                    batch = []
                # a preview on show, computed anew: the image itself; the page answers
                # "shown" (studio.served) once it shows it or passes
                head = {k: v for k, v in ev.items() if k != "data"}
                await self.ws.send_bytes(binary_message(head, ev["data"]))
            if batch:
                await self.ws.send_text(events_message(batch))

    async def _receive(self, text: str) -> None:
        try:
            msg = json.loads(text)
        except ValueError:
            return
        if not isinstance(msg, dict):
            return
        kind = msg.get("type")
        handler = {"params": self._params, "frame": self._frame, "commit": self._commit}.get(kind)
        if handler is not None:
            await handler(msg)
        elif kind == "shown" and isinstance(msg.get("digest"), str):
            self.studio.served(msg["digest"])

    async def _params(self, msg: dict) -> None:
        """A param change over the socket (the page's sliders): as POST /api/params,
        without an HTTP request per move; the answer carries the message's id."""
        changes = msg.get("changes")
        if not changes_shape(changes):
            res = {"ok": False, "errors": [{"text": "expected changes: [{node, param, value}]"}]}
        else:
            res = await self._thread(self.studio.set_params, changes)
        await self.ws.send_text(json.dumps({"type": "params", "id": msg.get("id"), **res}, default=str))

    async def _frame(self, msg: dict) -> None:
        name = msg.get("node", "")
        v = self.views.get(name) or live_view(self.studio, name)
        head = {"type": "frame", "node": name, "id": msg.get("id")}
        if v is None:
            head["error"] = f"node '{name}' has no live view"
            return await self.ws.send_text(json.dumps(head))
        self.views[name] = v
        try:
            info, png = await self._thread(frame_bytes, v, msg.get("values") or {},
                                           float(msg.get("exposure", 0) or 0), 0 if self.local else 1)
        except GraphkitError as e:
            head["error"] = str(e)
            return await self.ws.send_text(json.dumps(head))
        await self.ws.send_bytes(binary_message({**head, **info}, png))

    async def _commit(self, msg: dict) -> None:
        """A live view's values written into the graph (LiveView.commit, then set_params as
        any edit); with ``save`` (a file name) the graph is then saved there (as POST
        /api/save: only into the graph's folder), the name checked before anything changes.
        The answer carries the message's id."""
        name, save = msg.get("node", ""), msg.get("save")
        head = {"type": "commit", "node": name, "id": msg.get("id")}
        v = self.views.get(name) or live_view(self.studio, name)
        if v is None:
            return await self.ws.send_text(json.dumps({**head, "ok": False,
                                                       "errors": [{"text": f"node '{name}' has no live view"}]}))
        try:
            if save is not None:
                self.studio.save_path(str(save))
            changes = await self._thread(v.commit, msg.get("values") or {})
            res = await self._thread(self.studio.set_params, changes) if changes else {"ok": True}
            if res.get("ok") and save is not None:
                res["saved"] = await self._thread(self.studio.save_as, str(save))
        except GraphkitError as e:
            res = {"ok": False, "errors": [{"text": str(e)}]}
        self.views.pop(name, None)
        await self.ws.send_text(json.dumps({**head, **res}, default=str))
