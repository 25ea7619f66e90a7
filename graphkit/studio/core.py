"""The studio's graph session: one graph file, its edited params, runs through the cache
(runs.py), node states, the previews on show (live.py) and the state a page draws (state.py).

Everything here is independent of the web server (``app.py``, ``routes.py``), so it can be
driven and tested from Python.  A change of a param makes a new YAML text (``YamlDoc``), which is loaded
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
from typing import Any, Callable

import yaml

from ..errors import GraphError, GraphkitError, UsageError
from ..graphfile import load_graph
from ..runner import NodeOutcome
from ..store import Store
from .live import PREVIEWABLE, Previews
from .runs import Closing, Superseded, run_graph
from .state import snapshot
from .yamldoc import YamlDoc


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
        self.revision = 0  # counts the texts loaded: a page drops a state older than one it has
        self.undo_texts: list[str] = []  # the node editor's undo / redo: texts before each edit
        self.redo_texts: list[str] = []
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
        self.schema_cache: dict[str, Any] = {}  # node type → its params schema (state.py)
        self.previews = Previews(self._wake, self.emit, lambda: bool(self._listeners), self.memo)
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

    def emit(self, event: dict) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for fn in listeners:
            with contextlib.suppress(Exception):
                fn(event)

    def node_event(self, name: str, **fields) -> None:
        with self._lock:
            st = self.nodes.setdefault(name, {})
            st.update(fields)
            ev = {"type": "node", "name": name, **{k: v for k, v in st.items() if k != "t0"}}
        self.emit(ev)

    def background_event(self, name: str, fraction: float, message: str) -> None:
        """Progress of node ``name``'s work in the background (Context.background_progress),
        shown on the node beside its state, whichever run started it."""
        self.node_event(name, background=round(float(fraction), 3), background_message=message)

    # -- loading --------------------------------------------------------------------------
    def _try_load(self, doc: YamlDoc):
        """(graph, errors) for a document."""
        try:
            g = load_graph(self.path, self.registry, text=doc.text, parsed=doc.parsed())
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
            self.revision += 1
            names = list(g.nodes) if g else list(((doc.data() or {}).get("nodes") or {}))
            old = self.nodes
            self.nodes = {n: old.get(n, {"state": "idle", "seconds": None, "message": "", "digests": {}})
                          for n in names}
            if g is None:
                for n in self.nodes.values():
                    n.update(state="idle", message="")

    # -- edits ----------------------------------------------------------------------------
    def set_params(self, changes: list[dict]) -> dict:
        """Apply param changes ``[{"node": name or None, "param": p, "value": v}]``.

        Returns ``{"ok": True}`` or ``{"ok": False, "errors": [...]}`` (the loader's messages,
        ``file:line:col: error: …``, as ``graphkit run`` prints them), with ``"gen"``: the number
        of the run the change started, when it started one (a page then shows that run as
        running at once, not the last run's "ok" until the new run's first event).  A change
        that makes a valid graph invalid is not applied; on a graph that is already invalid it
        is (so its errors can be fixed one by one)."""
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
            gen = None
            if run:  # the new state goes out from the run, once its first preview on show has
                self._state_due = True  # (or STATE_DUE_S in), so the run starts at once
                gen = self.request_run()
        if not run:
            self.emit({"type": "state", "state": self.state()})
        return {"ok": not errors, "errors": errors, **({"gen": gen} if gen is not None else {})}

    # the loader's messages an edit may leave behind: a graph being built has unfed inputs and unset params
    _UNFINISHED = ("missing required input", "missing required param")

    def edit(self, edits: list[dict]) -> dict:
        """Apply node-editor edits (yamldoc.EDITS: add / remove / rename a node, set an input).

        The edited text goes through the same loader as ``graphkit validate``; an edit that
        brings a new error (other than an input not fed yet) is refused with the loader's
        messages and changes nothing.  ``{"ok": True}`` or ``{"ok": False, "errors": [...]}``."""
        with self._lock:
            try:
                doc = self.doc.with_edits(edits)
            except (ValueError, KeyError, TypeError) as e:
                return {"ok": False, "errors": [{"text": f"cannot edit the graph: {e}", "message": str(e)}]}
            except yaml.YAMLError as e:
                return {"ok": False, "errors": [{"text": f"cannot edit the graph file: {e}", "message": str(e)}]}
            loaded = self._try_load(doc)
            before = {e["message"] for e in self.errors}
            new = [e for e in loaded[1] if e["message"] not in before
                   and not any(u in e["message"] for u in self._UNFINISHED)]
            if new:
                return {"ok": False, "errors": new}
            self.undo_texts.append(self.doc.text)
            self.redo_texts.clear()
            return self._replace(doc, loaded)

    def undo(self, redo: bool = False) -> dict:
        """The text before the last edit (``redo``: after the last undone one) back."""
        with self._lock:
            src, dst = (self.redo_texts, self.undo_texts) if redo else (self.undo_texts, self.redo_texts)
            if not src:
                return {"ok": False, "errors": [{"text": "nothing to " + ("redo" if redo else "undo"), "message": ""}]}
            dst.append(self.doc.text)
            doc = YamlDoc(src.pop())
            return self._replace(doc, self._try_load(doc))

    def _replace(self, doc: YamlDoc, loaded) -> dict:
        """The studio on a new text (lock held): loaded, run when it validates, pages told."""
        self._load(doc, loaded)
        if self.graph is not None and self.autorun:
            self.request_run()
        self.emit({"type": "state", "state": self.state()})
        return {"ok": True, "errors": loaded[1]}

    def set_autorun(self, on: bool) -> None:
        self.autorun = bool(on)
        self.emit({"type": "state", "state": self.state()})
        if on and self.graph is not None:
            self.request_run()

    def save_path(self, path: str | os.PathLike) -> Path:
        """Where ``path`` (relative to the graph's folder) saves: a .yaml/.yml file in the
        graph's folder, else UsageError."""
        p = Path(path)
        if not p.is_absolute():
            p = Path(self.path).parent / p
        if p.suffix not in (".yaml", ".yml"):
            raise UsageError(f"{p}: a graph file name ends in .yaml or .yml")
        folder = Path(self.path).parent.resolve()
        if p.resolve().parent != folder:
            raise UsageError(f"{p}: the studio saves only into the graph's folder ({folder})")
        return p

    def save_as(self, path: str | os.PathLike) -> str:
        """Write the current graph (params as edited, comments kept) to ``path``."""
        p = self.save_path(path)
        with self._lock:
            text = self.doc.text
        # the saved file must load where it is (relative paths start at its folder)
        try:
            load_graph(str(p), self.registry, text=text)
        except GraphError as e:
            # a node whose plugin is not installed here is saved as it was written; other errors refuse
            if not all("unknown node type" in d.message for d in e.diagnostics):
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
        if p.resolve() == Path(self.path).resolve():
            with self._lock:
                self.saved_text = text  # the page no longer says "edited, not saved"
        return str(p)

    # -- runs -----------------------------------------------------------------------------
    def request_run(self) -> int:
        """Start a run of the current graph; a running one becomes stale.  Returns its number."""
        with self._lock:
            self.gen += 1
            self._pending = self.gen
            self._wake.notify_all()
            return self.gen

    def stop(self) -> None:
        """Stop the running run at its next node boundary (what it finished stays cached)."""
        with self._lock:
            self.gen += 1
            self._pending = None
            self._wake.notify_all()

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
            self.emit({"type": "run", **self.run_info})
            info = {"gen": gen, "status": "invalid"} if graph is None else self._run(gen, graph)
            with self._lock:
                self.run_info = info
                self._wake.notify_all()
            self.emit({"type": "run", **info})
            if info.get("status") in ("ok", "failed"):
                with self._lock:
                    self._state_due = False
                self.emit({"type": "state", "state": self.state()})
            else:
                self.send_due_state()
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
        try:
            return run_graph(self, gen, graph)
        except (Superseded, Closing):
            return {"gen": gen, "status": "superseded"}
        except Exception as e:  # noqa: BLE001 - a bug: keep the studio alive, say it
            return {"gen": gen, "status": "error", "message": f"internal error: {type(e).__name__}: {e}"}

    def current(self, gen: int) -> bool:
        """Whether run ``gen`` is still the one to finish (no newer change, not closing)."""
        return self.gen == gen and not self.closing

    def check_gen(self, gen: int) -> None:
        """Stop run ``gen`` if the studio is closing or a newer change made it stale."""
        if self.closing:
            raise Closing("the studio is closing")
        if self.gen != gen:
            raise Superseded("superseded by a newer change")

    def reset_states(self, names) -> None:
        """Nodes a run is about to compute lose their failed / blocked / running state."""
        with self._lock:
            for n in names:
                st = self.nodes.setdefault(n, {})
                if st.get("state") in ("failed", "blocked", "running"):
                    st.update(state="idle", message="")

    def prune_memo(self, outcomes: dict[str, NodeOutcome]) -> None:
        """Values in memory: only the outputs of the last run's nodes."""
        keep = {d for o in outcomes.values() for v in o.outputs.values()
                for d in (v if isinstance(v, list) else [v])}
        with self._lock:
            for d in [d for d in self.memo if d not in keep]:
                self.memo.pop(d, None)
        self.previews.keep_only(keep)

    def exported(self, files: list[str], manifest: dict | None) -> None:
        """A run's export to --out: its files and (when it could be read back) its manifest."""
        with self._lock:
            self.files = files
            if manifest is not None:
                self.manifest = manifest

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
    def preview(self, node: str, port: str, exposure: float = 0.0, max_side: int = 0,
                level: int = 1) -> bytes | None:
        """PNG of ``node.port`` for the page (None: no value yet; b"": not an image; ``level``:
        imaging.png's, 0 for a page on the loopback).

        The request marks the preview as on show: a later run that computes that node anew
        pushes it to the pages and waits until it has gone out (live.py, Previews)."""
        ptype, v, d = self._value(node, port)
        if v is None:
            return None
        if ptype.name not in PREVIEWABLE:
            return b""
        return self.previews.png(node, port, ptype, v, d, exposure, max_side, level)

    def served(self, digest: str) -> None:
        """A page got the preview of ``digest`` (pushed over its websocket)."""
        self.previews.served(digest)

    STATE_DUE_S = 0.3  # a run sends the state of a param change after this at the latest

    def send_due_state(self) -> None:
        with self._lock:
            due, self._state_due = self._state_due, False
        if due:
            self.emit({"type": "state", "state": self.state()})

    # -- state ----------------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a page needs to draw the studio (JSON; state.py)."""
        with self._lock:
            return snapshot(self)

    # -- closing --------------------------------------------------------------------------
    def close(self, timeout: float = 5.0) -> None:
        """Stop: the running node may finish computing, but nothing more is written."""
        with self._write_lock:  # waits for a write in progress
            self.closing = True
        with self._lock:
            self._wake.notify_all()
        self._worker.join(timeout)


