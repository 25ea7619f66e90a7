"""What a run would do, and why: per node instance "cached" or "would run" with the reasons.

``graphkit run --dry-run``, ``graphkit status`` and ``graphkit show --status`` print it; other
tools (the studio) call :func:`status`::

    report = graphkit.status("graphs/face_ring.yaml", cache=".graphkit-cache")
    for n in report.nodes.values():
        print(n.state, n.node, [r.message for r in n.reasons])

A node is *cached* when its key is in the store.  Otherwise it *would run*, and each reason
names a part of its key that differs from the last run of this graph in this cache (like
Snakemake's ``--reason``): ``params``, ``input-file``, ``node-version``, ``backend``, ``recipe``
(the key recipe), ``provenance`` (the graph upstream of a node that embeds it), ``inputs``
(an upstream value changed), ``upstream`` (an upstream node would run first, so this key is not
known yet), ``new`` (not computed before) or ``missing`` (same key as the last run, but the entry
is gone: removed by gc or ``verify --repair``).
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

from .executor import graph_id
from .model import Graph
from .runner import Session
from .store import Store

CACHED = "cached"
WOULD_RUN = "would run"


@dataclass
class Reason:
    part: str  # which key part (see the module docstring)
    message: str


@dataclass
class NodeStatus:
    node: str  # the node's (instance's) name, e.g. relit[az030]
    type: str
    base: str  # its name in the graph file
    instance: str | None
    sweep: str | None
    state: str  # CACHED or WOULD_RUN
    key: str | None  # None while an upstream node would run (its inputs are not known yet)
    backend: str
    reasons: list[Reason] = field(default_factory=list)
    parts: dict | None = field(default=None, repr=False)  # readable key parts (None if key unknown)


@dataclass
class StatusReport:
    graph: Graph
    nodes: dict[str, NodeStatus]

    @property
    def would_run(self) -> list[str]:
        return [n for n, s in self.nodes.items() if s.state == WOULD_RUN]

    @property
    def cached(self) -> list[str]:
        return [n for n, s in self.nodes.items() if s.state == CACHED]

    def by_base(self) -> dict[str, list[NodeStatus]]:
        out: dict[str, list[NodeStatus]] = {}
        for s in self.nodes.values():
            out.setdefault(s.base, []).append(s)
        return out

    def to_json(self) -> dict:
        return {"graph": self.graph.name, "path": self.graph.path,
                "counts": {CACHED: len(self.cached), WOULD_RUN: len(self.would_run)},
                "nodes": [{k: v for k, v in asdict(s).items() if k != "parts"} for s in self.nodes.values()]}

    def lines(self, only_running: bool = False) -> list[str]:
        """One line per node instance (the text ``--dry-run`` prints)."""
        width = max((len(n) for n in self.nodes), default=4)
        twidth = max((len(s.type) for s in self.nodes.values()), default=4)
        out = []
        for s in self.nodes.values():
            if only_running and s.state == CACHED:
                continue
            why = "; ".join(r.message for r in s.reasons)
            out.append(f"{s.state:<9}  {s.node:<{width}}  {s.type:<{twidth}}  {why}".rstrip())
        return out

    def summary(self) -> str:
        return f"{self.graph.name}: {len(self.would_run)} would run, {len(self.cached)} cached"


def status(graph, cache: str | os.PathLike | Store | None = None, *, registry=None,
           backends: list[str] | None = None, overrides: dict | None = None,
           outputs: list[str] | None = None) -> StatusReport:
    """Per node instance of ``graph`` (a path, a dict or a loaded Graph): cached or would run, why.

    Nothing is computed and nothing is written to the store.
    """
    from .graphfile import load
    from .registry import default_registry

    registry = registry or default_registry()
    graph = load(graph, registry, overrides)
    if outputs:
        graph.select_outputs(outputs)
    if isinstance(cache, Store):
        store = cache
    else:  # not opened: a dry run creates nothing
        loc, options, _ = graph.cache_setting(cache)
        store = Store(loc, options=options)
    session = Session(graph, registry, store, backends)
    targets = sorted({n for n, _ in graph.outputs.values()})
    return StatusReport(graph, walk(session, graph.upstream(targets)))


def walk(session: Session, order: list[str]) -> dict[str, NodeStatus]:
    """The status of each node in ``order`` (a topological order) without running anything."""
    graph = session.graph
    last = session.store.last_run(graph_id(graph)) or {}
    known: dict[str, dict | None] = {}  # node -> output digests, None when it would run
    out: dict[str, NodeStatus] = {}
    for n in order:
        out[n], known[n] = _status(session, n, known, last.get(n))
    return out


def _status(session: Session, n: str, known: dict, prev: dict | None) -> tuple[NodeStatus, dict | None]:
    """(node ``n``'s status, its output digests when they are known without running it);
    ``known``: the same for the nodes before it, ``prev``: its entry in the last run."""
    g = session.graph.nodes[n]
    st = NodeStatus(n, g.type, g.base or n, g.instance, g.sweep, WOULD_RUN, None, session.backend_for(g)[0])
    pending = [s for s in dict.fromkeys(src for _, src, _ in g.edges()) if known.get(s) is None]
    if pending:
        st.reasons = _waiting(session, n, pending, prev)
        return st, None
    key, parts = session.key(g, g.map_inputs(lambda s, sp: known[s][sp]))
    st.key, st.parts = key, session.readable_parts(g, parts)
    rec = session.store.get_record(key)
    if rec is None:
        st.reasons = reasons(st.parts, prev, session.graph, n)
        return st, None
    st.state = CACHED
    return st, {p: o["digest"] for p, o in rec["outputs"].items()}


def _waiting(session: Session, n: str, pending: list[str], prev: dict | None) -> list[Reason]:
    """Why a node whose inputs are not computed yet would run: they would run first, and
    what changed in its own key parts (params, files, versions) since its last run."""
    g = session.graph.nodes[n]
    static, _ = session.static_parts(g)
    own = session.readable_parts(g, static)
    shown = ", ".join(pending[:3]) + (f" and {len(pending) - 3} more" if len(pending) > 3 else "")
    out = [Reason("upstream", f"upstream {shown} would run first")]
    if prev is not None:
        out += [r for r in reasons(own, prev, session.graph, n, inputs=False) if r.part != "missing"]
    return out


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    else:
        out[prefix] = d
    return out


def _short(v: Any) -> str:
    t = repr(v)
    return t if len(t) <= 40 else t[:37] + "..."


def reasons(cur: dict, prev: dict | None, graph: Graph, node: str, inputs: bool = True) -> list[Reason]:
    """Why a node whose key is not in the store would run: the key parts that changed since
    its last run (``prev``: the last run's entry for it, or None)."""
    if prev is None:
        return [Reason("new", "not computed before")]
    old = prev.get("parts") or {}
    checks = _CHECKS + ((_inputs_changed,) if inputs else ())
    out = [r for check in checks for r in [check(old, cur, graph, node)] if r is not None]
    return out or [Reason("missing", "same key as the last run, but its cache entry is gone (gc or verify --repair)")]


def _changed(old: dict, cur: dict, part: str) -> bool:
    return cur.get(part, "<absent>") != old.get(part, "<absent>")


def _part_changed(part: str, reason: str, label: str):
    """A check of one key part, worded "<label> <old> → <new>"."""
    def check(old, cur, graph, node):
        if _changed(old, cur, part):
            return Reason(reason, f"{label} {old.get(part)} → {cur.get(part)}")
        return None
    return check


def _backend_changed(old, cur, graph, node):
    # the numpy reference is the node's own compute: its version is the node version
    if _changed(old, cur, "backend") or (_changed(old, cur, "backend_version") and cur.get("backend") != "numpy"):
        a = f"{old.get('backend')} {old.get('backend_version')}"
        b = f"{cur.get('backend')} {cur.get('backend_version')}"
        return Reason("backend", f"backend {a} → {b}")
    return None


def _params_changed(old, cur, graph, node):
    a, b = _flat(old.get("params", {})), _flat(cur.get("params", {}))
    diff = [k for k in sorted(set(a) | set(b)) if a.get(k, "<absent>") != b.get(k, "<absent>")]
    if not diff:
        return None
    shown = ", ".join(f"{k} {_short(a.get(k, '<absent>'))} → {_short(b.get(k, '<absent>'))}" for k in diff[:3])
    return Reason("params", f"param changed: {shown}" + (f" (+{len(diff) - 3} more)" if len(diff) > 3 else ""))


def _files_changed(old, cur, graph, node):
    a, b = old.get("files") or {}, cur.get("files") or {}
    fdiff = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    if not fdiff:
        return None
    g = graph.nodes[node]
    shown = ", ".join(f"{k} ({os.path.relpath(g.files[k], graph.base_dir) if k in g.files else 'gone'})" for k in fdiff[:3])
    return Reason("input-file", f"input file changed: {shown}")


def _provenance_changed(old, cur, graph, node):
    if _changed(old, cur, "recipe_digest"):
        return Reason("provenance", "the graph upstream of it changed (its output embeds the recipe)")
    return None


def _inputs_changed(old, cur, graph, node):
    a, b = old.get("inputs") or {}, cur.get("inputs") or {}
    ports = [p for p in sorted(set(a) | set(b)) if a.get(p) != b.get(p)]
    if not ports:
        return None
    g = graph.nodes[node]
    srcs = {p: sorted({f"{s}.{sp}" for pp, s, sp in g.edges() if pp == p}) for p in ports}
    shown = ", ".join(f"'{p}' (from {', '.join(srcs[p][:2]) + (' …' if len(srcs[p]) > 2 else '')})" for p in ports[:3])
    return Reason("inputs", f"input changed: {shown}")


# in the order a dry run lists them
_CHECKS = (
    _part_changed("recipe", "recipe", "cache key recipe"),
    _part_changed("node_type", "node-type", "node type"),
    _part_changed("node_version", "node-version", "node version"),
    _backend_changed,
    _params_changed,
    _files_changed,
    _provenance_changed,
)


__all__ = ["status", "walk", "StatusReport", "NodeStatus", "Reason", "CACHED", "WOULD_RUN"]
