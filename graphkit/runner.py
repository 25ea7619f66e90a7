"""Running one node: backend choice, cache key, lookup, compute, store.

:class:`Session` holds what one run shares (graph, registry, store, backend order, in-memory
values).  :meth:`Session.run_node` is the unit both executors call — the local thread pool
and Dask workers — so every executor produces the same keys and the same bytes.

Values read back from the store are checked against their digest (:meth:`Store.load_value`);
a damaged or missing one is recomputed from the node that made it (:meth:`Session.value`),
with one notice line.

Thread counts.  A node's bytes must not depend on the machine, so a process that computes
nodes runs every BLAS pool at one thread (threadpoolctl, plus ``OPENBLAS_NUM_THREADS`` and
friends for libraries a node loads later): a BLAS call splits its sums differently with more
threads, and a fit (FitSkinPhong) then ends a few ulps apart.  Parallelism comes from the
engine's ``--jobs`` and from deterministic row bands inside nodes.
"""
from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Callable

from .contract import check_inputs
from .errors import BackendCannotRun, BadInput, GraphkitError, NodeFailed
from .model import GNode, Graph
from . import keys
from .hashing import file_digest
from .node import Context, probe
from .registry import NUMPY, Registry
from .store import DamagedEntry, Store, value_parts

BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
_blas_lock = threading.Lock()
_blas_seen = -1  # len(sys.modules) when the BLAS pools were last pinned


def pin_blas_threads() -> None:
    """Run every BLAS pool of this process at one thread (see the module docstring).

    Cheap when nothing was imported since the last call: one length compare."""
    global _blas_seen
    if len(sys.modules) == _blas_seen:
        return
    with _blas_lock:
        for var in BLAS_ENV:  # libraries loaded from now on start with one thread
            os.environ[var] = "1"
        try:
            from threadpoolctl import threadpool_limits

            threadpool_limits(1, user_api="blas")
        except ImportError:  # pragma: no cover - a dependency; the env vars still hold
            pass
        _blas_seen = len(sys.modules)


@dataclass
class NodeOutcome:
    name: str
    type: str
    key: str
    hit: bool
    seconds: float
    backend: str
    backend_version: str
    outputs: dict[str, str]  # port -> value digest
    parts: dict = field(default_factory=dict)


def readable_params(params) -> Any:
    try:
        return params.model_dump(mode="json")
    except Exception:  # noqa: BLE001 - params with arrays etc.: show their repr
        return {k: repr(getattr(params, k)) for k in type(params).model_fields}


class Session:
    """Shared state of one run."""

    def __init__(self, graph: Graph, registry: Registry, store: Store,
                 backend_order: list[str] | None = None,
                 notice: Callable[[str], None] = lambda msg: None,
                 report: Callable[[str, float, str], None] = lambda node, frac, msg: None,
                 on_outputs: Callable[[str, dict[str, Any], dict[str, Any]], None] | None = None):
        self.graph, self.registry, self.store = graph, registry, store
        self.backend_order = list(backend_order or [NUMPY])
        if NUMPY not in self.backend_order:
            self.backend_order.append(NUMPY)
        self.notice = notice
        self.report = report
        #: called as on_outputs(node, {port: digest}, {port: value}) once a computed node's
        #: outputs are checked and hashed, before they are stored (the studio pushes a preview
        #: from the in-memory value while the store writes run); an error in it fails the node
        self.on_outputs = on_outputs
        self.interactive = False  # a live session's run (the studio): Context.interactive
        #: background(node, fraction, message): Context.background_progress (from any thread)
        self.background: Callable[[str, float, str], None] = lambda node, frac, msg: None
        if store.on_notice is None:
            store.on_notice = notice
        self._outcomes: dict[str, NodeOutcome] = {}  # this process's outcomes (regeneration)
        #: the notes of the last run of this graph, when read at the start of this one (executor.read_ahead)
        self.last_notes: dict | None = None
        self._producers: dict[str, tuple[str, str]] = {}  # value digest -> (node, port)
        self.memo: dict[str, Any] = {}  # digest -> value, for values made or loaded in this process
        self._memo_lock = threading.Lock()
        self._backends: dict[str, tuple[str, type, str]] = {}
        self._noticed: set[tuple[str, str]] = set()
        self._files: dict[str, str] = {}
        self._static: dict[str, tuple[dict, dict[str, bytes]]] = {}  # per node: key parts that never vary
        self._readable: dict[str, Any] = {}

    # -- backends ------------------------------------------------------------------------
    def backend_for(self, g: GNode) -> tuple[str, type, str]:
        """(name, class, version) of the backend that computes node ``g``."""
        if g.name in self._backends:
            return self._backends[g.name]
        reg = self.registry
        if g.backend:
            choice = g.backend  # pinned: validated (and probed) when the graph was loaded
        else:
            choice = NUMPY
            for b in self.backend_order:
                if b == NUMPY:
                    break
                if b not in reg.backends.get(g.type, {}):
                    continue
                bcls = reg.backend_class(g.type, b)
                why = probe(bcls)
                declined = why is None and _declines(bcls)
                if why is None and not declined:
                    choice = b
                    break
                if (g.type, b) not in self._noticed:
                    self._noticed.add((g.type, b))
                    self.notice(f"notice: backend '{b}' for {g.type} is not chosen by preference here ({declined}); using numpy"
                                if declined else
                                f"notice: backend '{b}' for {g.type} is not available here ({why}); using numpy")
        cls = reg.backend_class(g.type, choice)
        version = cls.version
        self._backends[g.name] = (choice, cls, version)
        return self._backends[g.name]

    # -- keys ------------------------------------------------------------------------------
    def static_parts(self, g: GNode) -> tuple[dict, dict[str, bytes]]:
        """The key parts of ``g`` that do not depend on its inputs, and their encoding."""
        if g.name not in self._static:
            bname, _, bver = self.backend_for(g)
            files = {p: self.file_digest(path) for p, path in sorted(g.files.items())} if g.files else None
            recipe = self.graph.recipe_digest(g.name) if g.cls.provenance else None
            parts = keys.static_parts(g.type, g.cls.version, bname, bver, g.params, files, recipe)
            self._static[g.name] = (parts, keys.encode_static(parts))
        return self._static[g.name]

    def key(self, g: GNode, input_digests: dict) -> tuple[str, dict]:
        """(cache key, key parts) of node ``g`` given the digests of its inputs (graphkit.keys)."""
        static, encoded = self.static_parts(g)
        return keys.node_key(static, encoded, input_digests)

    def readable_parts(self, g: GNode, parts: dict) -> dict:
        if g.name not in self._readable:
            self._readable[g.name] = readable_params(g.params)
        return {**parts, "params": self._readable[g.name]}

    def file_digest(self, path: str) -> str:
        if path not in self._files:
            try:
                self._files[path] = file_digest(path, self.store.memo_file)
            except OSError as e:
                raise GraphkitError(f"cannot read input file {path}: {e.strerror or e}") from None
        return self._files[path]

    # -- values ----------------------------------------------------------------------------
    def value(self, digest: str, ptype, source: tuple[str, str] | None = None) -> Any:
        """The value named ``digest`` (port type ``ptype``), from memory or the store.

        ``source`` = (node, port) that made it.  A stored value that is damaged or missing is
        recomputed by that node (found from the outcomes of this process when not given)."""
        with self._memo_lock:
            if digest in self.memo:
                return self.memo[digest]
        try:
            v = self.store.load_value(digest, ptype)
        except DamagedEntry as e:
            source = source or self._producers.get(digest)
            if source is None:
                raise
            return self._regenerate(source[0], source[1], digest, e)
        with self._memo_lock:
            self.memo[digest] = v
        return v

    def prefetch_values(self, digests) -> None:
        """Values about to be read (exports, a report): those not in memory are read from the
        store together (one batch on an object store)."""
        with self._memo_lock:
            todo = [d for d in digests if d not in self.memo]
        self.store.prefetch_values(todo)

    def output_value(self, node: str, port: str) -> Any:
        """The value of ``node.port`` in this run (after the node has run)."""
        o = self._outcomes[node]
        return self.value(o.outputs[port], self.graph.nodes[node].cls.out_ports[port].type, (node, port))

    def _outcome(self, name: str) -> NodeOutcome:
        """This run's outcome of node ``name``, looking it (and its upstream) up if needed."""
        for n in self.graph.pending(name, self._outcomes):  # sources first, no recursion
            self.run_node(n, self.graph.nodes[n].map_inputs(lambda src, sport: self._outcomes[src].outputs[sport]))
        return self._outcomes[name]

    def _regenerate(self, name: str, port: str, digest: str, why: DamagedEntry) -> Any:
        """Recompute node ``name`` because its stored output ``port`` (``digest``) is damaged."""
        from .errors import CacheError

        g = self.graph.nodes[name]
        o = self._outcome(name)
        _, bcls, _ = self.backend_for(g)
        ptype = g.cls.out_ports[port].type
        with self.store.key_lock(o.key):
            with self._memo_lock:
                if digest in self.memo:
                    return self.memo[digest]
            with contextlib.suppress(DamagedEntry):  # another run may have repaired it meanwhile
                v = self.store.load_value(digest, ptype)
                with self._memo_lock:
                    self.memo[digest] = v
                return v
            if isinstance(why, DamagedEntry) and why.why == "is missing":
                self.notice(f"notice: cache object {digest[:16]} ({name}.{port}) is missing; recomputing {name}")
            outputs = self._compute(g, bcls, o.key, o.parts, o.parts.get("inputs", {}))
        if outputs.get(port) != digest:
            raise CacheError(f"node '{name}' ({g.type}) gave other bytes when recomputed to replace a damaged "
                             f"cache entry (is its compute deterministic?); its new result is stored: run again")
        with self._memo_lock:
            return self.memo[digest]

    # -- the unit of work ------------------------------------------------------------------
    def run_node(self, name: str, input_digests: dict[str, str], missed: bool = False) -> NodeOutcome:
        """Node ``name``'s outcome: a hit, or computed under its key's lock.  ``missed``: the
        caller has just looked it up (:meth:`cached_many`) and found nothing, or expects it to
        miss (executor.probably_new): on an object store it is looked up beside the lock's request."""
        try:
            return self._run_node(name, input_digests, missed)
        except BackendCannotRun as e:
            g = self.graph.nodes[name]
            bname = self._backends[name][0]
            if g.backend or bname == NUMPY:  # pinned: refuse, naming node, backend and reason
                err = BadInput(None, f"backend '{bname}' cannot run here: {e.reason}")
                err.node, err.node_type = g.name, g.type
                raise err from None
            with self._memo_lock:  # preferred: this node runs (and is keyed) as numpy
                cls = self.registry.backend_class(g.type, NUMPY)
                self._backends[name] = (NUMPY, cls, cls.version)
                self._static.pop(name, None)
                first = (g.type, bname, "run") not in self._noticed
                self._noticed.add((g.type, bname, "run"))
            if first:
                self.notice(f"notice: backend '{bname}' for {g.type} cannot run node '{name}' here ({e.reason}); using numpy")
            return self._run_node(name, input_digests, missed)

    def cached(self, name: str, input_digests: dict[str, str]) -> NodeOutcome | None:
        """Node ``name``'s outcome when its result is in the store (a hit), else None; nothing
        is computed or locked, so an executor can resolve the hits in its own thread."""
        g = self.graph.nodes[name]
        t0 = time.perf_counter()
        key, parts = self.key(g, input_digests)
        rec = self._lookup(g, key, parts, touch=True)
        return None if rec is None else self._hit(g, key, parts, rec, t0)

    def cached_many(self, nodes: list[tuple[str, dict[str, str]]]) -> dict[str, NodeOutcome | None]:
        """:meth:`cached` of many nodes (name, input digests) whose inputs are known: their
        records are read together (one concurrent batch on an object store)."""
        t0 = time.perf_counter()
        keyed = [(self.graph.nodes[name], *self.key(self.graph.nodes[name], digests)) for name, digests in nodes]
        recs = self.store.get_records([key for _, key, _ in keyed], touch=True)
        out = {}
        for g, key, parts in keyed:
            rec = self._describes(g, key, parts, recs[key])
            out[g.name] = None if rec is None else self._hit(g, key, parts, rec, t0)
        return out

    def _hit(self, g: GNode, key: str, parts: dict, rec: dict, t0: float) -> NodeOutcome:
        bname, _, bver = self.backend_for(g)
        outputs = {p: o["digest"] for p, o in rec["outputs"].items()}
        return self._remember(NodeOutcome(g.name, g.type, key, True, time.perf_counter() - t0, bname, bver, outputs, parts))

    def _run_node(self, name: str, input_digests: dict[str, str], missed: bool = False) -> NodeOutcome:
        # the look just before the lock; on an object store after a caller's miss, it goes out
        # together with the lock's request (one round trip, not two; None: looked at below)
        beside = missed and self.store.reads_together
        hit = None if beside else self.cached(name, input_digests)
        if hit is not None:
            return hit
        g = self.graph.nodes[name]
        bname, bcls, bver = self.backend_for(g)
        t0 = time.perf_counter()
        key, parts = self.key(g, input_digests)
        looking = _beside(self._lookup, g, key, parts, True) if beside else None
        with self.store.key_lock(key, name) as waited:
            # another run held the key (it was computing it): look again.  A lock taken at
            # once (False) means nobody computed the key since the miss just above (or the look
            # beside the lock), bar a run that did all of it within that round trip: at worst a
            # node is computed twice, with the same bytes (None: this lock cannot tell, so look again)
            rec = looking.result() if looking is not None else None
            if waited is not False:
                rec = self._lookup(g, key, parts)
            if rec is None:
                outputs = self._compute(g, bcls, key, parts, input_digests)
        if rec is not None:
            return self._hit(g, key, parts, rec, t0)
        self.store.commit(force=False)  # group commit: at most one syncfs per interval
        return self._remember(NodeOutcome(name, g.type, key, False, time.perf_counter() - t0, bname, bver, outputs, parts))

    _BOUND = ("recipe", "node_type", "node_version", "backend", "backend_version")

    def _lookup(self, g: GNode, key: str, parts: dict, touch: bool = False) -> dict | None:
        """The record of ``key`` if it is intact (Store.get_record) and describes this very
        computation: same type, versions, backend and input digests as ``parts``."""
        return self._describes(g, key, parts, self.store.get_record(key, touch=touch))

    def _describes(self, g: GNode, key: str, parts: dict, rec: dict | None) -> dict | None:
        """``rec`` if it describes this very computation (else quarantined: None)."""
        if rec is None:
            return None
        rp = rec.get("parts") or {}
        if (rp.get("inputs") != parts["inputs"] or any(rp.get(k) != parts.get(k) for k in self._BOUND)
                or not self._same_params(rp.get("params"), g)):
            self.store.quarantine_record(key, f"cache record {key[:16]} describes another computation")
            return None
        return rec

    def _same_params(self, stored, g: GNode) -> bool:
        if g.name not in self._readable:
            self._readable[g.name] = readable_params(g.params)
        mine = self._readable[g.name]
        if stored == mine:
            return True
        import json  # NaN != NaN: compare the JSON texts before calling it another computation

        return json.dumps(stored, sort_keys=True) == json.dumps(mine, sort_keys=True)

    def _remember(self, o: NodeOutcome) -> NodeOutcome:
        self._outcomes[o.name] = o
        for port, d in o.outputs.items():
            self._producers.setdefault(d, (o.name, port))
        return o

    def _compute(self, g: GNode, bcls: type, key: str, parts: dict, input_digests: dict[str, str]) -> dict[str, str]:
        """Compute node ``g`` with backend ``bcls`` and store its outputs under ``key``; {port: digest}."""
        inputs = self._input_values(g, input_digests)
        pin_blas_threads()
        ctx = Context(node=g.name, node_type=g.type, key=key, graph_name=self.graph.name,
                      recipe_digest=parts.get("recipe_digest", ""), base_dir=self.graph.base_dir,
                      inputs=dict(input_digests),
                      report=lambda frac, msg: self.report(g.name, frac, msg),
                      tell=lambda msg: self.notice(f"notice: {g.name} ({g.type}): {msg}"),
                      interactive=self.interactive,
                      background=lambda frac, msg: self.background(g.name, frac, msg))
        t0 = time.perf_counter()
        result = _call_compute(g, bcls, ctx, inputs)
        seconds = time.perf_counter() - t0
        staged = _staged_outputs(g, result)
        if self.on_outputs is not None:
            self.on_outputs(g.name, {port: vp[2] for port, _, _, vp in staged},
                            {port: v for port, _, v, _ in staged})
        return self._store_outputs(g, key, parts, staged, seconds)

    def _input_values(self, g: GNode, input_digests: dict) -> dict[str, Any]:
        """{port: value} of ``g``'s inputs (a list of values for a variadic port)."""
        inputs = {}
        for port, d in input_digests.items():
            ptype = g.cls.in_ports[port].type
            src = g.inputs.get(port)
            if isinstance(d, list):
                srcs = src if isinstance(src, list) and len(src) == len(d) else [None] * len(d)
                inputs[port] = [self.value(x, ptype, s) for x, s in zip(d, srcs)]
            else:
                inputs[port] = self.value(d, ptype, src if isinstance(src, tuple) else None)
        return inputs

    def _store_outputs(self, g: GNode, key: str, parts: dict, staged: list, seconds: float) -> dict[str, str]:
        """Store the checked outputs ``staged`` and the record of ``key``; {port: digest}."""
        digests, rec_out = {}, {}
        stored = self.store.put_values([(p.type, v, vp) for _, p, v, vp in staged])
        for (port, p, v, vp), d in zip(staged, stored):
            digests[port] = d
            rec_out[port] = {"digest": d, "type": p.type.name}
            with self._memo_lock:
                self.memo[d] = v
        record = {
            "key": key, "node": g.name,
            "parts": self.readable_parts(g, parts),
            "outputs": rec_out,
            "seconds": round(seconds, 6) if math.isfinite(seconds) else 0.0,
        }
        self.store.put_record(key, record)
        return digests


def _beside(fn: Callable, *args) -> Future:
    """``fn(*args)`` in a thread of its own, started now (a request sent beside another)."""
    fut: Future = Future()

    def run() -> None:
        try:
            fut.set_result(fn(*args))
        except BaseException as e:  # noqa: BLE001 - raised where the result is asked for
            fut.set_exception(e)
    threading.Thread(target=run, daemon=True, name="graphkit-lookup").start()
    return fut


def _call_compute(g: GNode, bcls: type, ctx: Context, inputs: dict[str, Any]) -> Any:
    """What ``bcls(g.params, ctx).compute(**inputs)`` returns; its errors named after the node."""
    try:
        check_inputs(g.cls, inputs)
        return bcls(g.params, ctx).compute(**inputs)
    except BadInput as e:
        e.node, e.node_type = g.name, g.type
        raise
    except GraphkitError:
        raise
    except Exception as e:  # noqa: BLE001 - any other failure is the node's
        raise NodeFailed(g.name, g.type, e) from e


def _output_dict(g: GNode, result: Any) -> dict[str, Any]:
    """``result`` as {port: value}: a node with one output may return the bare value."""
    outs = g.cls.out_ports
    if not isinstance(result, dict) or (len(outs) == 1 and set(result) != set(outs)):
        if len(outs) == 1:
            result = {next(iter(outs)): result}
    if not isinstance(result, dict) or set(result) != set(outs):
        got = sorted(result) if isinstance(result, dict) else type(result).__name__
        raise NodeFailed(g.name, g.type, TypeError(f"compute returned {got}, expected outputs {sorted(outs)}"))
    return result


def _staged_outputs(g: GNode, result: Any) -> list[tuple[str, Any, Any, tuple]]:
    """[(port, port declaration, value, value parts)] of ``result``, each checked against its
    port type; the arrays are made read-only (consumers share the value: an accidental in-place
    edit fails)."""
    result = _output_dict(g, result)
    staged = []
    for port, p in g.cls.out_ports.items():
        v = result[port]
        problem = p.type.check(v)
        if problem:
            raise NodeFailed(g.name, g.type, TypeError(f"output '{port}': {problem}"))
        vp = value_parts(p.type, v)
        for a in vp[1]:
            try:
                a.flags.writeable = False
            except ValueError:  # a view of a buffer it does not own
                pass
        staged.append((port, p, v, vp))
    return staged


def _declines(bcls) -> str | None:
    """The backend's reason not to be chosen by preference here (None: it may be)."""
    try:
        return bcls.declines_preference()
    except Exception as e:  # noqa: BLE001 - a broken hook must not break the run
        return f"{type(e).__name__}: {e}"
