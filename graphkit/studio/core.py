"""The studio's model: one graph file, its edited params, runs through the cache, node states.

Everything here is independent of the web server (``app.py``), so it can be driven and
tested from Python.  A change of a param makes a new YAML text (``YamlDoc``), which is loaded
with the same loader as ``graphkit run`` (same checks, same messages); when it validates, a
run starts through the cache (only what depends on the change computes).  A newer change
supersedes a running one: the stale run stops at the next node boundary (or at the next
progress report inside a long node), and what it had finished stays cached.
"""
from __future__ import annotations

import contextlib
import os
import threading
import time
from pathlib import Path
from collections import OrderedDict
from typing import Any, Callable

from ..errors import GraphError, GraphkitError, UsageError
from ..executor import Progress, RunResult, record_last_run, run_local
from ..publish import export_outputs
from ..graphfile import load_graph
from ..runner import NodeOutcome, Session
from ..store import Store
from .yamldoc import YamlDoc


class Superseded(GraphkitError):
    """A newer change (or the server closing) made this run stale."""


class Closing(GraphkitError):
    """The studio is closing: nothing more is written."""


class GuardedStore:
    """The run's store, with writes refused once the studio closes and each write finished
    before it exits (so Ctrl-C never leaves a half-written entry behind)."""

    def __init__(self, store: Store, studio: "Studio"):
        self._store, self._studio = store, studio

    def __getattr__(self, name):
        return getattr(self._store, name)

    def _guard(self, fn, *a, **kw):
        with self._studio.write_guard():
            return fn(*a, **kw)

    def put_value(self, *a, **kw):
        return self._guard(self._store.put_value, *a, **kw)

    def put_record(self, *a, **kw):
        return self._guard(self._store.put_record, *a, **kw)

    def save_run(self, *a, **kw):
        return self._guard(self._store.save_run, *a, **kw)


class _RunProgress(Progress):
    """Forwards node events to the studio and stops a stale run."""

    def __init__(self, studio: "Studio", gen: int):
        self.studio, self.gen = studio, gen
        self.t0 = time.time()
        self.running_nodes: list[str] = []
        self.outcomes: dict[str, NodeOutcome] = {}
        self.pushed: dict[str, list[str]] = {}  # node -> digests of previews pushed before its store writes

    def outputs(self, node, digests, values):
        """Session.on_outputs: a node computed anew, its outputs hashed, not stored yet.  The
        previews on show of it are encoded and pushed now, from the values in memory, so the
        page decodes them while the store writes run (done() then waits for "shown")."""
        try:
            self.pushed[node] = self.studio._encode_watched(node, digests, values)
        except Exception:  # noqa: BLE001 - a preview must not fail the node; done() retries
            self.pushed.pop(node, None)

    def _check(self):
        if self.studio.closing:
            raise Closing("the studio is closing")
        if self.studio.gen != self.gen:
            raise Superseded("superseded by a newer change")

    def running(self, node, node_type):
        self._check()
        if time.time() - self.t0 > self.studio.STATE_DUE_S:
            self.studio._send_due_state()
        self.running_nodes.append(node)
        if node in self.outcomes:  # done by an earlier pass of this run
            return
        self.studio._node_event(node, state="running", seconds=None, message="", t0=time.time())

    def done(self, o: NodeOutcome):
        with contextlib.suppress(ValueError):
            self.running_nodes.remove(o.name)
        if o.name in self.outcomes:  # a later pass (after a failure elsewhere) found it cached
            return
        self.outcomes[o.name] = o
        wanted = self.pushed.pop(o.name, None)  # pushed before the store writes (outputs())
        if wanted is None:
            wanted = [] if o.hit else self.studio._encode_watched(o.name, o.outputs)
        self.studio._node_event(o.name, state="cached" if o.hit else "done", seconds=round(o.seconds, 4),
                                message="", digests=o.outputs, backend=o.backend)
        if wanted:
            self.studio._await_served(wanted, self.gen)
            self.studio._send_due_state()

    def report(self, node, fraction, message):
        self._check()
        self.studio._node_event(node, progress=round(float(fraction), 3), message=message)

    def notice(self, message):
        self.studio._emit({"type": "notice", "message": message})


def _layout(nodes: dict[str, list[str]]) -> dict[str, tuple[int, int]]:
    """Layered DAG layout: layer = longest path from a source; rows in file order."""
    layer: dict[str, int] = {}
    rows: dict[int, int] = {}
    out = {}
    for n in nodes:
        lx = _depth(n, nodes, layer)
        out[n] = (lx, rows.get(lx, 0))
        rows[lx] = rows.get(lx, 0) + 1
    return out


def _depth(root: str, nodes: dict[str, list[str]], layer: dict[str, int]) -> int:
    """The longest path from a source to ``root`` (memoised in ``layer``), with an explicit
    stack: a graph's depth is not limited by Python's recursion limit.  An edge back onto the
    path being walked (a cycle, reported by the loader) counts as coming from a source."""
    if root in layer:
        return layer[root]
    path, on_path, pending, best = [root], {root}, [iter(nodes.get(root, []))], [0]
    while path:
        s = next(pending[-1], None)
        if s is None:  # every source of path[-1] seen: its layer is known
            n, d = path.pop(), best.pop()
            pending.pop()
            on_path.discard(n)
            layer[n] = d
            if best:
                best[-1] = max(best[-1], d + 1)
        elif s in layer:
            best[-1] = max(best[-1], layer[s] + 1)
        elif s in on_path:
            best[-1] = max(best[-1], 1)
        elif s in nodes:
            path.append(s)
            on_path.add(s)
            pending.append(iter(nodes.get(s, [])))
            best.append(0)
    return layer[root]


def _refs(v) -> list[str]:
    if isinstance(v, str) and "." in v:
        return [v.rpartition(".")[0]]
    if isinstance(v, list):
        return [r for x in v for r in _refs(x)]
    return []


class Studio:
    """One graph file opened in the studio."""

    def __init__(self, graph_path: str | os.PathLike, cache: str, out: str | None = None,
                 registry=None, backends: list[str] | None = None, jobs: int = 1,
                 autorun: bool = True, freeze_gc: bool = False):
        from ..registry import default_registry

        self.path = os.path.abspath(str(graph_path))
        try:
            text = Path(self.path).read_text(encoding="utf-8")
        except FileNotFoundError:
            raise UsageError(f"{graph_path}: graph file not found") from None
        except (OSError, UnicodeDecodeError) as e:
            raise UsageError(f"{graph_path}: cannot read graph file: {e}") from None
        self.display_path = str(graph_path)
        self.registry = registry or default_registry()
        self.store = Store(cache).open()
        self.out = out
        self.backends = backends
        self.jobs = max(1, int(jobs))
        self.autorun = autorun
        # the server process (graphkit serve) moves what its runs imported (modules, the node
        # libraries' state) out of the garbage collector's sight after a run that imported
        # something: a full collection over them took 70-110 ms every few slider moves, on the
        # preview's path.  Only after imports (len(sys.modules) grew), so what a later run
        # leaves behind (old graphs, …) is still collected, not kept for good.
        self._gc_modules = 0 if freeze_gc else None
        self.doc = YamlDoc(text)
        self.saved_text = text
        self.graph = None
        self.errors: list[dict] = []
        self.problems = list(self.registry.problems)
        self.nodes: dict[str, dict] = {}
        self.memo: dict[str, Any] = {}
        self.gen = 0
        self.run_info: dict = {"gen": 0, "status": "idle"}
        self.manifest: dict | None = None
        self.files: list[str] = []
        self.closing = False
        self._lock = threading.RLock()
        self._write_lock = threading.RLock()  # re-entrant: export_outputs writes report thumbnails through the guarded store
        self._wake = threading.Condition(self._lock)
        self._pending: int | None = None
        self._listeners: list[Callable[[dict], None]] = []
        self._views: dict[str, Any] = {}
        self._schemas: dict[str, Any] = {}
        # previews: PNGs by (digest, exposure, max side, PNG level), the previews the page asked
        # for lately ((node, port) → {(exposure, max side, level): time}), and the digests a run waits
        # to see served before it goes on (Studio._preview_first)
        self._png: "OrderedDict[tuple, bytes]" = OrderedDict()
        self._watch: dict[tuple[str, str], dict[tuple[float, int, int], float]] = {}
        self._served_digests: set[str] = set()
        self._state_due = False  # a param change whose state the pages have not had yet
        self._load(self.doc)
        self._worker = threading.Thread(target=self._loop, name="graphkit-studio", daemon=True)
        self._worker.start()
        if self.graph is not None and autorun:
            self.request_run()

    # -- events ---------------------------------------------------------------------------
    def subscribe(self, fn: Callable[[dict], None]) -> Callable[[], None]:
        with self._lock:
            self._listeners.append(fn)
        return lambda: self._unsubscribe(fn)

    def _unsubscribe(self, fn):
        with self._lock, contextlib.suppress(ValueError):
            self._listeners.remove(fn)

    def _emit(self, event: dict) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for fn in listeners:
            with contextlib.suppress(Exception):
                fn(event)

    def _node_event(self, name: str, **fields) -> None:
        with self._lock:
            st = self.nodes.setdefault(name, {})
            st.update(fields)
            ev = {"type": "node", "name": name, **{k: v for k, v in st.items() if k != "t0"}}
        self._emit(ev)

    # -- loading --------------------------------------------------------------------------
    def _try_load(self, doc: YamlDoc):
        """(graph, errors) for a document."""
        try:
            g = load_graph(self.path, self.registry, text=doc.text)
            return g, []
        except GraphError as e:
            return None, [{"file": d.file, "line": d.line, "col": d.col, "message": d.message,
                           "text": str(d)} for d in e.diagnostics]
        except GraphkitError as e:
            return None, [{"file": self.display_path, "line": 1, "col": 1, "message": str(e), "text": str(e)}]

    def _load(self, doc: YamlDoc, loaded=None) -> None:
        g, errors = loaded if loaded is not None else self._try_load(doc)
        with self._lock:
            self.doc, self.graph, self.errors = doc, g, errors
            names = list(g.nodes) if g else list(((doc.data() or {}).get("nodes") or {}))
            old = self.nodes
            self.nodes = {n: old.get(n, {"state": "idle", "seconds": None, "message": "", "digests": {}})
                          for n in names}
            if g is None:
                for n in self.nodes.values():
                    n.update(state="idle", message="")
            self._views = {}

    # -- edits ----------------------------------------------------------------------------
    def set_params(self, changes: list[dict]) -> dict:
        """Apply param changes ``[{"node": name or None, "param": p, "value": v}]``.

        Returns ``{"ok": True}`` or ``{"ok": False, "errors": [...]}`` (the loader's messages,
        ``file:line:col: error: …``, as ``graphkit run`` prints them).  A change that makes a
        valid graph invalid is not applied; on a graph that is already invalid it is (so its
        errors can be fixed one by one)."""
        with self._lock:
            try:
                doc = self.doc.with_params([(c.get("node"), c["param"], c.get("value")) for c in changes])
            except (KeyError, TypeError, AttributeError) as e:
                return {"ok": False, "errors": [{"text": f"cannot apply the change: {e}", "message": str(e)}]}
            except Exception as e:  # noqa: BLE001 - ruamel refusing the document
                return {"ok": False, "errors": [{"text": f"cannot edit the graph file: {e}", "message": str(e)}]}
            g, errors = self._try_load(doc)
            if errors and self.graph is not None:
                return {"ok": False, "errors": errors}
            self._load(doc, (g, errors))  # loaded once: the same text gives the same graph
            run = self.graph is not None and self.autorun
            if run:  # the new state goes out from the run, once its first preview on show has
                self._state_due = True  # (or STATE_DUE_S in), so the run starts at once
                self.request_run()
        if not run:
            self._emit({"type": "state", "state": self.state()})
        return {"ok": not errors, "errors": errors}

    def set_autorun(self, on: bool) -> None:
        self.autorun = bool(on)
        self._emit({"type": "state", "state": self.state()})
        if on and self.graph is not None:
            self.request_run()

    def save_as(self, path: str | os.PathLike) -> str:
        """Write the current graph (params as edited, comments kept) to ``path``."""
        p = Path(path)
        if not p.is_absolute():
            p = Path(self.path).parent / p
        if p.suffix not in (".yaml", ".yml"):
            raise UsageError(f"{p}: a graph file name ends in .yaml or .yml")
        with self._lock:
            text = self.doc.text
        # the saved file must load where it is (relative paths start at its folder)
        try:
            load_graph(str(p), self.registry, text=text)
        except GraphError as e:
            if os.path.dirname(str(p)) != os.path.dirname(self.path):
                raise UsageError(f"{p}: the graph would not load from there:\n{e}") from None
            raise
        tmp = p.parent / f".{p.name}.{os.getpid()}.tmp"
        try:
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, p)
        except OSError as e:
            tmp.unlink(missing_ok=True)
            raise UsageError(f"cannot write {p}: {e.strerror or e}") from None
        return str(p)

    # -- runs -----------------------------------------------------------------------------
    def request_run(self) -> int:
        """Start a run of the current graph; a running one becomes stale.  Returns its number."""
        with self._lock:
            self.gen += 1
            self._pending = self.gen
            self._wake.notify_all()
            return self.gen

    def wait_idle(self, timeout: float = 60.0) -> dict:
        """Block until no run is pending or running (tests, benchmarks); the last run info."""
        end = time.time() + timeout
        with self._lock:
            while self._pending is not None or self.run_info.get("status") == "running":
                left = end - time.time()
                if left <= 0:
                    raise TimeoutError("the studio's run did not finish in time")
                self._wake.wait(min(left, 0.5))
            return dict(self.run_info)

    def _loop(self):
        while True:
            with self._lock:
                while self._pending is None and not self.closing:
                    self._wake.wait()
                if self.closing:
                    return
                gen, self._pending = self._pending, None
                graph = self.graph
                self.run_info = {"gen": gen, "status": "running", "started": time.time()}
            self._emit({"type": "run", **self.run_info})
            if graph is None:
                info = {"gen": gen, "status": "invalid"}
            else:
                try:
                    info = self._run(gen, graph)
                except (Superseded, Closing):
                    info = {"gen": gen, "status": "superseded"}
                except Exception as e:  # noqa: BLE001 - a bug: keep the studio alive, say it
                    info = {"gen": gen, "status": "error", "message": f"internal error: {type(e).__name__}: {e}"}
            with self._lock:
                self.run_info = info
                self._wake.notify_all()
            self._emit({"type": "run", **info})
            if info.get("status") in ("ok", "failed"):
                with self._lock:
                    self._state_due = False
                self._emit({"type": "state", "state": self.state()})
            else:
                self._send_due_state()
            self._freeze_imports()

    def _freeze_imports(self) -> None:
        import sys

        if self._gc_modules is None or len(sys.modules) == self._gc_modules:
            return
        with self._lock:
            if self._pending is not None:  # a newer change waits: freeze after it
                return
        import gc

        gc.collect()  # garbage goes first; what lives now (mostly imports) is kept out of later scans
        gc.freeze()
        self._gc_modules = len(sys.modules)

    @contextlib.contextmanager
    def write_guard(self):
        with self._write_lock:
            if self.closing:
                raise Closing("the studio is closing")
            yield

    def _run(self, gen: int, graph) -> dict:
        t0 = time.perf_counter()
        progress = _RunProgress(self, gen)
        store = GuardedStore(self.store, self)
        session = Session(graph, self.registry, store, self.backends,
                          notice=progress.notice, report=progress.report, on_outputs=progress.outputs)
        session.memo = self.memo  # values stay in memory between runs of the studio
        targets = sorted({n for n, _ in graph.outputs.values()})
        needed = graph.upstream(targets)
        with self._lock:
            for n in needed:
                st = self.nodes.setdefault(n, {})
                if st.get("state") in ("failed", "blocked", "running"):
                    st.update(state="idle", message="")
        failed: dict[str, str] = {}
        blocked: set[str] = set()
        global_error = None
        while True:
            todo = [t for t in targets if t not in failed and t not in blocked]
            if not todo:
                break
            try:
                run_local(session, todo, self.jobs, progress, first=self._watched_nodes(graph))
                break
            except (Superseded, Closing):
                raise
            except GraphkitError as e:
                node = getattr(e, "node", None)
                if node is None and len(progress.running_nodes) == 1:
                    node = progress.running_nodes[0]
                progress.running_nodes.clear()
                if node is None or node in failed:
                    global_error = str(e)
                    break
                failed[node] = str(e)
                self._node_event(node, state="failed", message=str(e), seconds=None)
                for d in self._downstream(graph, node):
                    if d not in failed:
                        blocked.add(d)
                        self._node_event(d, state="blocked", message=f"waits for '{node}', which failed")
        self._check_gen(gen)
        outcomes = dict(progress.outcomes)
        seconds = time.perf_counter() - t0
        result = RunResult(graph.name, outcomes, seconds, "studio")
        info = {"gen": gen, "seconds": round(seconds, 4),
                "computed": sorted(n for n, o in outcomes.items() if not o.hit),
                "cached": sorted(n for n, o in outcomes.items() if o.hit)}
        if outcomes:
            with contextlib.suppress(GraphkitError):
                record_last_run(session, result)
        self._prune_memo(outcomes)
        if failed or global_error:
            info.update(status="failed", failed=failed, message=global_error or "")
            return info
        if self.out is not None:
            with self.write_guard():
                self._check_gen(gen)
                files = export_outputs(session, result, self.out,
                                       {"targets": list(graph.outputs), "studio": True})
            with self._lock:
                self.files = [str(f) for f in files]
                import json

                with contextlib.suppress(OSError, ValueError):
                    self.manifest = json.loads(Path(self.out, "manifest.json").read_text())
            info["files"] = len(files)
        info["status"] = "ok"
        return info

    def _watched_nodes(self, graph) -> list[str]:
        """The node(s) of the preview a page asked for last (and of those asked for with it,
        within 50 ms: its panel's thumbnails): a run computes them, and what they need,
        first, so a slider's preview does not wait for the rest of the graph."""
        with self._lock:
            if not self._listeners:
                return []
            last = {n: max(seen.values()) for (n, _), seen in self._watch.items() if seen and n in graph.nodes}
        if not last:
            return []
        newest = max(last.values())
        return sorted(n for n, t in last.items() if t >= newest - 0.05 and time.time() - t < self.WATCH_S)

    def _check_gen(self, gen):
        if self.closing:
            raise Closing("the studio is closing")
        if self.gen != gen:
            raise Superseded("superseded by a newer change")

    @staticmethod
    def _downstream(graph, node: str) -> list[str]:
        out, frontier = [], {node}
        for n in graph.order():
            if graph.nodes[n].sources() & frontier and n not in frontier:
                frontier.add(n)
                out.append(n)
        return out

    def _prune_memo(self, outcomes: dict[str, NodeOutcome]) -> None:
        keep = {d for o in outcomes.values() for v in o.outputs.values()
                for d in (v if isinstance(v, list) else [v])}
        with self._lock:
            for d in [d for d in self.memo if d not in keep]:
                self.memo.pop(d, None)
            self._served_digests &= keep

    # -- values ---------------------------------------------------------------------------
    def value(self, node: str, port: str):
        """The current value of ``node.port`` (None when not computed yet)."""
        ptype, v, _ = self._value(node, port)
        return ptype, v

    def _value(self, node: str, port: str):
        """(port type, value, digest) of ``node.port`` now (Nones when not computed yet)."""
        with self._lock:
            g = self.graph
            d = (self.nodes.get(node) or {}).get("digests", {}).get(port)
        if g is None or d is None or node not in g.nodes or port not in g.nodes[node].cls.out_ports:
            return None, None, None
        ptype = g.nodes[node].cls.out_ports[port].type
        v = self.memo.get(d)
        if v is None:
            v = self.store.load_value(d, ptype)
        return ptype, v, d

    def input_values(self, node: str) -> dict | None:
        """The values of ``node``'s inputs (as its compute gets them), or None if not all known."""
        g = self.graph
        if g is None or node not in g.nodes:
            return None
        gn = g.nodes[node]
        missing = []

        def get(src, sport):
            _, v = self.value(src, sport)
            if v is None:
                missing.append(src)
            return v

        vals = gn.map_inputs(get)
        return None if missing else vals

    # -- previews -------------------------------------------------------------------------
    PNG_CACHE = 24  # previews kept (a few exposures / sizes of the outputs on show)
    WATCH_S = 120.0  # a preview the page asked for within this many seconds is "on show"
    HOLD_S = 0.25  # how long a run waits for a page to fetch a new preview on show

    def preview(self, node: str, port: str, exposure: float = 0.0, max_side: int = 0,
                level: int = 1) -> bytes | None:
        """PNG of ``node.port`` for the page (None: no value yet; b"": not an image; ``level``:
        imaging.png's, 0 for a page on the loopback).

        The request marks the preview as on show: when a later run computes that node anew,
        the run encodes it at once (same exposure and size), pushes it to the pages (a
        ``preview`` event with the image: no request round trip) and waits until it has gone
        out before it goes on with the rest of the graph (``_await_served``).  The push to a
        page on the loopback (``level`` 0) is raw RGBA (``format: rgba``, width × height × 4
        bytes) that its canvas takes without decoding; elsewhere the PNG (``format: png``)."""
        from .imaging import preview_png

        ptype, v, d = self._value(node, port)
        if v is None:
            return None
        if ptype.name not in ("Image", "Mask"):
            return b""
        var = (float(exposure), int(max_side), int(level))
        with self._lock:
            now = time.time()
            seen = self._watch.setdefault((node, port), {})
            for k in [k for k, t in seen.items() if now - t > self.WATCH_S]:
                del seen[k]
            seen[var] = now
            data = self._png.get((d, *var))
        if data is None:
            data = preview_png(ptype.name, v, *var)
            self._keep_png((d, *var), data)
        with self._lock:
            self._served_digests.add(d)
            self._wake.notify_all()
        return data

    def _keep_png(self, key, data: bytes) -> None:
        with self._lock:
            self._png[key] = data
            self._png.move_to_end(key)
            while len(self._png) > self.PNG_CACHE:
                self._png.popitem(last=False)

    def _encode_watched(self, name: str, outputs: dict, values: dict | None = None) -> list[str]:
        """Encode and push the previews on show of node ``name``, computed anew with
        ``outputs`` (port → digest; ``values``: port → value, else from memory); their digests."""
        from .imaging import png, preview_rgb, rgba

        g = self.graph
        if g is None or name not in g.nodes:
            return []
        now = time.time()
        with self._lock:
            if not self._listeners:  # no page open
                return []
            todo = []
            for (node, port), variants in self._watch.items():
                d = outputs.get(port) if node == name else None
                if not isinstance(d, str):
                    continue
                for var, t in variants.items():
                    key = (d, var[0], var[1], "rgba" if var[2] == 0 else var[2])
                    if now - t < self.WATCH_S and key not in self._png:
                        todo.append((port, d, var, key))
        out = []
        for port, d, (exposure, max_side, level), key in todo:
            ptype = g.nodes[name].cls.out_ports[port].type
            v = values.get(port) if values else self.memo.get(d)
            if v is None or ptype.name not in ("Image", "Mask"):
                continue
            rgb8 = preview_rgb(ptype.name, v, exposure, max_side)
            # a page on the loopback takes raw pixels (no PNG to encode here, none to decode
            # there); elsewhere the PNG (a twentieth of the bytes)
            fmt = "rgba" if level == 0 else "png"
            data = rgba(rgb8) if fmt == "rgba" else png(rgb8, level)
            self._keep_png(key, data)
            out.append((port, d, {"exposure": exposure, "max": max_side, "level": level, "format": fmt,
                                  "width": int(rgb8.shape[1]), "height": int(rgb8.shape[0])}, data))
        with self._lock:
            self._served_digests.difference_update(d for _, d, _, _ in out)
        for port, d, head, data in out:  # pages on show take it from here
            self._emit({"type": "preview", "node": name, "port": port, "digest": d, **head, "data": data})
        return [d for _, d, _, _ in out]

    STATE_DUE_S = 0.3  # a run sends the state of a param change after this at the latest

    def _send_due_state(self) -> None:
        with self._lock:
            due, self._state_due = self._state_due, False
        if due:
            self._emit({"type": "state", "state": self.state()})

    def served(self, digest: str) -> None:

        """A page got the preview of ``digest`` (pushed over its websocket)."""
        with self._lock:
            self._served_digests.add(digest)
            self._wake.notify_all()

    def _await_served(self, digests: list[str], gen: int) -> None:
        """Wait (at most HOLD_S) until a page has fetched the previews of ``digests``, so
        the rest of the run (file writers, sheets, the --out export) does not compete with
        sending them; a newer change or closing ends the wait."""
        end = time.monotonic() + self.HOLD_S
        with self._lock:
            while not set(digests) <= self._served_digests and self.gen == gen and not self.closing:
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._wake.wait(left)

    # -- state ----------------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a page needs to draw the studio (JSON)."""
        from ..runner import readable_params
        from ..schema import node_schema
        from .views import view_for

        with self._lock:
            g, doc = self.graph, self.doc
            data = doc.data() or {}
            raw_nodes = data.get("nodes") if isinstance(data.get("nodes"), dict) else {}
            nodes, edges, schemas, defs = [], [], {}, {}
            deps: dict[str, list[str]] = {}
            for name in self.nodes:
                spec = raw_nodes.get(name) if isinstance(raw_nodes.get(name), dict) else {}
                if g is not None and name in g.nodes:
                    gn = g.nodes[name]
                    typ = gn.type
                    ins = [[p, s, sp] for p, s, sp in gn.edges()]
                    outs = {p: port.type.name for p, port in gn.cls.out_ports.items()}
                    values = readable_params(gn.params)
                    deps[name] = sorted(gn.sources())
                else:
                    typ = spec.get("type") if isinstance(spec.get("type"), str) else "?"
                    ins = []
                    for p, ref in (spec.get("inputs") or {}).items() if isinstance(spec.get("inputs"), dict) else []:
                        for r in (ref if isinstance(ref, list) else [ref]):
                            if isinstance(r, str) and "." in r:
                                s, _, sp = r.rpartition(".")
                                ins.append([p, s, sp])
                    outs = {}
                    values = spec.get("params") if isinstance(spec.get("params"), dict) else {}
                    deps[name] = sorted({s for _, s, _ in ins})
                    with contextlib.suppress(Exception):
                        outs = {p: port.type.name for p, port in self.registry.node_class(typ).out_ports.items()}
                if typ not in schemas and typ in self.registry.nodes:
                    if typ not in self._schemas:  # pydantic's schema of a type never changes
                        self._schemas[typ] = None
                        with contextlib.suppress(Exception):
                            s, d = node_schema(self.registry, typ)
                            self._schemas[typ] = ({"params": s["properties"]["params"],
                                                   "description": s["description"]}, d)
                    if self._schemas[typ] is not None:
                        schemas[typ] = self._schemas[typ][0]
                        defs.update(self._schemas[typ][1])
                raw = spec.get("params") if isinstance(spec.get("params"), dict) else {}
                st = {k: v for k, v in self.nodes[name].items() if k != "t0"}
                view = None
                with contextlib.suppress(Exception):
                    view = view_for(self.registry, typ)
                nodes.append({"name": name, "type": typ, "inputs": ins, "outputs": outs,
                              "params": values, "raw_params": raw, "doc": spec.get("doc", ""),
                              "view": view.describe() if view else None, **st})
                edges.extend([s, name] for _, s, _ in ins)
            pos = _layout(deps)
            for n in nodes:
                n["layer"], n["row"] = pos.get(n["name"], (0, 0))
            gparams = data.get("params") if isinstance(data.get("params"), dict) else {}
            gschema = self._graph_param_schemas(raw_nodes, schemas, defs)
            outputs = {k: list(v) for k, v in g.outputs.items()} if g else {}
            return {
                "graph": {"name": g.name if g else (data.get("name") or Path(self.path).stem),
                          "path": self.display_path, "description": (data.get("description") or "").strip(),
                          "valid": g is not None, "dirty": doc.text != self.saved_text},
                "errors": list(self.errors), "problems": self.problems,
                "nodes": nodes, "graph_params": gparams, "graph_param_schema": gschema,
                "schemas": schemas, "defs": defs, "outputs": outputs,
                "preview": self._default_preview(g),
                "run": {k: v for k, v in self.run_info.items()}, "autorun": self.autorun,
                "out": self.out, "files": list(self.files),
                "manifest": self._manifest_summary(),
            }

    def _manifest_summary(self):
        m = self.manifest
        if not m:
            return None
        return {"finished": m.get("finished"), "nodes": {n: {"hit": v.get("hit"), "seconds": v.get("seconds")}
                                                         for n, v in (m.get("nodes") or {}).items()}}

    @staticmethod
    def _graph_param_schemas(raw_nodes, schemas, defs) -> dict:
        """A graph param takes the schema of the first node param that is exactly it."""
        import re

        ref = re.compile(r"^\s*\$\{params\.([A-Za-z_][A-Za-z0-9_]*)\}\s*$")
        out: dict[str, dict] = {}

        def walk(v, sch, where):
            if isinstance(v, str):
                m = ref.match(v)
                if m and m.group(1) not in out and sch is not None:
                    out[m.group(1)] = {"schema": sch, "used_by": where}
            elif isinstance(v, list):
                items = None
                if isinstance(sch, dict):
                    s0 = _unwrap(sch, defs)
                    items = s0.get("prefixItems") or s0.get("items")
                for i, x in enumerate(v):
                    it = items[i] if isinstance(items, list) and i < len(items) else (
                        items if isinstance(items, dict) else None)
                    walk(x, it, f"{where}[{i}]")

        for n, spec in raw_nodes.items():
            if not isinstance(spec, dict) or not isinstance(spec.get("params"), dict):
                continue
            typ = spec.get("type")
            props = ((schemas.get(typ) or {}).get("params") or {}).get("properties") or {}
            for k, v in spec["params"].items():
                walk(v, props.get(k), f"{n}.{k}")
        return out

    def _default_preview(self, g):
        if g is None:
            return None
        outs = sorted(g.outputs.items(), key=lambda kv: "sheet" not in kv[0].lower())  # contact sheets first
        for oname, (node, port) in outs:
            cls = g.nodes[node].cls
            t = cls.out_ports[port].type.name
            if t in ("Image", "Mask"):
                return [node, port]
            # a File writer: preview what it writes
            for p, src, sport in g.nodes[node].edges():
                if g.nodes[src].cls.out_ports[sport].type.name in ("Image", "Mask"):
                    return [src, sport]
        for n, gn in g.nodes.items():
            for p, port in gn.cls.out_ports.items():
                if port.type.name in ("Image", "Mask"):
                    return [n, p]
        return None

    # -- closing --------------------------------------------------------------------------
    def close(self, timeout: float = 5.0) -> None:
        """Stop: the running node may finish computing, but nothing more is written."""
        with self._write_lock:  # waits for a write in progress
            self.closing = True
        with self._lock:
            self._wake.notify_all()
        self._worker.join(timeout)


def _unwrap(s: dict, defs: dict) -> dict:
    """A param schema without the ``${params.X}`` alternative and with its $ref resolved."""
    if not isinstance(s, dict):
        return {}
    if "anyOf" in s and len(s["anyOf"]) == 2 and s["anyOf"][1].get("pattern", "").startswith(r"\$\{"):
        s = {**s["anyOf"][0], "description": s.get("description", s["anyOf"][0].get("description", ""))}
    ref = s.get("$ref")
    if isinstance(ref, str) and ref.startswith("#/$defs/"):
        s = {**defs.get(ref.split("/")[-1], {}), **{k: v for k, v in s.items() if k != "$ref"}}
    return s
