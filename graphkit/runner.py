"""Running one node: backend choice, cache key, lookup, compute, store.

:class:`Session` holds what one run shares (graph, registry, store, backend order, in-memory
values).  :meth:`Session.run_node` is the unit both executors call — the local thread pool
and Dask workers — so every executor produces the same keys and the same bytes.
"""
from __future__ import annotations

import contextlib
import hashlib
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from .errors import BackendCannotRun, BadInput, GraphkitError, NodeFailed
from .graphfile import GNode, Graph
from .hashing import RECIPE_VERSION, canonical_items, canonical_merge, file_digest
from .node import Context, probe
from .registry import NUMPY, Registry
from .store import Store, value_parts


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
                 report: Callable[[str, float, str], None] = lambda node, frac, msg: None):
        self.graph, self.registry, self.store = graph, registry, store
        self.backend_order = list(backend_order or [NUMPY])
        if NUMPY not in self.backend_order:
            self.backend_order.append(NUMPY)
        self.notice = notice
        self.report = report
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
            parts = {
                "recipe": RECIPE_VERSION,
                "node_type": g.type,
                "node_version": g.cls.version,
                "backend": bname,
                "backend_version": bver,
                "params": g.params,
            }
            if g.files:
                parts["files"] = {p: self.file_digest(path) for p, path in sorted(g.files.items())}
            if g.cls.provenance:
                parts["recipe_digest"] = self.graph.recipe_digest(g.name)
            self._static[g.name] = (parts, canonical_items(parts))
        return self._static[g.name]

    def key(self, g: GNode, input_digests: dict) -> tuple[str, dict]:
        """(cache key, key parts) of node ``g`` given the digests of its inputs.

        key = BLAKE2b-128(canonical(parts)), parts = recipe version, node type and version,
        backend name and version, params, input digests, input-file digests and, for nodes that
        embed provenance, the recipe digest.
        """
        static, encoded = self.static_parts(g)
        inputs = {"inputs": dict(sorted(input_digests.items()))}
        key = hashlib.blake2b(canonical_merge(encoded, inputs), digest_size=16).hexdigest()
        return key, {**static, **inputs}

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
    def value(self, digest: str, ptype) -> Any:
        with self._memo_lock:
            if digest in self.memo:
                return self.memo[digest]
        v = self.store.load_value(digest, ptype)
        with self._memo_lock:
            self.memo[digest] = v
        return v

    # -- the unit of work ------------------------------------------------------------------
    def run_node(self, name: str, input_digests: dict[str, str]) -> NodeOutcome:
        try:
            return self._run_node(name, input_digests)
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
            return self._run_node(name, input_digests)

    def _run_node(self, name: str, input_digests: dict[str, str]) -> NodeOutcome:
        g = self.graph.nodes[name]
        bname, bcls, bver = self.backend_for(g)
        t0 = time.perf_counter()
        key, parts = self.key(g, input_digests)
        rec = self.store.get_record(key, touch=True)
        if rec is None:
            with self.store.key_lock(key):
                rec = self.store.get_record(key)  # another process may have made it meanwhile
                if rec is None:
                    outputs = self._compute(g, bcls, key, parts, input_digests)
                    return NodeOutcome(name, g.type, key, False, time.perf_counter() - t0, bname, bver,
                                       outputs, parts)
        outputs = {p: o["digest"] for p, o in rec["outputs"].items()}
        return NodeOutcome(name, g.type, key, True, time.perf_counter() - t0, bname, bver, outputs, parts)

    def _compute(self, g: GNode, bcls: type, key: str, parts: dict, input_digests: dict[str, str]) -> dict[str, str]:
        inputs = {}
        for port, d in input_digests.items():
            ptype = g.cls.in_ports[port].type
            inputs[port] = [self.value(x, ptype) for x in d] if isinstance(d, list) else self.value(d, ptype)
        ctx = Context(node=g.name, node_type=g.type, key=key, graph_name=self.graph.name,
                      recipe_digest=parts.get("recipe_digest", ""), base_dir=self.graph.base_dir,
                      report=lambda frac, msg: self.report(g.name, frac, msg))
        t0 = time.perf_counter()
        try:
            inst = bcls(g.params, ctx)
            result = inst.compute(**inputs)
        except BadInput as e:
            e.node, e.node_type = g.name, g.type
            raise
        except GraphkitError:
            raise
        except Exception as e:  # noqa: BLE001 - any other failure is the node's
            raise NodeFailed(g.name, g.type, e) from e
        seconds = time.perf_counter() - t0
        outs = g.cls.out_ports
        if not isinstance(result, dict) or (len(outs) == 1 and set(result) != set(outs)):
            if len(outs) == 1:
                result = {next(iter(outs)): result}
        if not isinstance(result, dict) or set(result) != set(outs):
            got = sorted(result) if isinstance(result, dict) else type(result).__name__
            raise NodeFailed(g.name, g.type, TypeError(f"compute returned {got}, expected outputs {sorted(outs)}"))
        digests, rec_out, staged = {}, {}, []
        for port, p in outs.items():
            v = result[port]
            problem = p.type.check(v)
            if problem:
                raise NodeFailed(g.name, g.type, TypeError(f"output '{port}': {problem}"))
            vp = value_parts(p.type, v)
            for a in vp[1]:  # consumers share the value: make accidental in-place edits fail
                with contextlib.suppress(ValueError):
                    a.flags.writeable = False
            staged.append((port, p, v, vp))
        for port, p, v, vp in staged:
            d = self.store.put_value(p.type, v, vp)
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


def _declines(bcls) -> str | None:
    """The backend's reason not to be chosen by preference here (None: it may be)."""
    try:
        return bcls.declines_preference()
    except Exception as e:  # noqa: BLE001 - a broken hook must not break the run
        return f"{type(e).__name__}: {e}"
