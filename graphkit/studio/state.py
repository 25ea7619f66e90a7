"""The studio's state as a page gets it (JSON): the graph's nodes with their ports, params,
schemas, live views and run states, laid out in layers, and the graph's own params.

A graph that does not validate still shows: its nodes come from the YAML as written.
"""
from __future__ import annotations

import contextlib
import re
from pathlib import Path

from .live import PREVIEWABLE


def _dict(v) -> dict:
    return v if isinstance(v, dict) else {}


def snapshot(studio) -> dict:
    """Everything a page needs to draw ``studio`` (the caller holds its lock)."""
    g, doc = studio.graph, studio.doc
    data = doc.data() or {}
    raw_nodes = _dict(data.get("nodes"))
    nodes, schemas, defs = [], {}, {}
    deps: dict[str, list[str]] = {}
    for name in studio.nodes:
        spec = _dict(raw_nodes.get(_base(studio.graph, name)))
        entry, deps[name] = _node(studio, name, spec)
        _add_schema(studio, entry["type"], schemas, defs)
        nodes.append(entry)
    pos = _layout(deps)
    for n in nodes:
        n["layer"], n["row"] = pos.get(n["name"], (0, 0))
    return {
        "graph": {"name": g.name if g else (data.get("name") or Path(studio.path).stem),
                  "path": studio.display_path, "description": (data.get("description") or "").strip(),
                  "valid": g is not None, "dirty": doc.text != studio.saved_text},
        "errors": list(studio.errors), "problems": studio.problems,
        "nodes": nodes, "graph_params": _dict(data.get("params")),
        "graph_param_schema": _graph_param_schemas(raw_nodes, schemas, defs),
        "schemas": schemas, "defs": defs,
        "outputs": {k: list(v) for k, v in g.outputs.items()} if g else {},
        "preview": _default_preview(g),
        "run": dict(studio.run_info), "autorun": studio.autorun,
        "revision": studio.revision, "undo": len(studio.undo_texts), "redo": len(studio.redo_texts),
        "out": studio.out, "files": list(studio.files),
        "manifest": _manifest_summary(studio.manifest),
    }


def _node(studio, name: str, spec: dict) -> tuple[dict, list[str]]:
    """(a node's entry, the nodes it depends on): from the graph, or as written when the
    graph does not validate."""
    from .views import view_for

    g = studio.graph
    if g is not None and name in g.nodes:
        typ, ins, outs, values, deps = _from_graph(g.nodes[name])
    else:
        typ, ins, outs, values, deps = _as_written(spec, studio.registry)
    st = {k: v for k, v in studio.nodes[name].items() if k != "t0"}
    view = None
    with contextlib.suppress(Exception):
        view = view_for(studio.registry, typ)
    return {"name": name, "base": _base(g, name), "type": typ, "inputs": ins, "outputs": outs,
            "params": values, "raw_params": _dict(spec.get("params")), "doc": spec.get("doc", ""),
            "missing": typ not in studio.registry.nodes,
            "view": view.describe() if view else None, **st}, deps


def _base(g, name: str) -> str:
    """The graph file's name of node ``name`` (a sweep's instance ``lamp[ring00]`` is ``lamp``):
    the node its params and inputs are edited in."""
    gn = g.nodes.get(name) if g is not None else None
    return (gn.base or name) if gn is not None else name


def _from_graph(gn):
    from ..runner import readable_params

    return (gn.type, [[p, s, sp] for p, s, sp in gn.edges()],
            {p: port.type.name for p, port in gn.cls.out_ports.items()},
            readable_params(gn.params), sorted(gn.sources()))


def _as_written(spec: dict, registry):
    typ = spec.get("type") if isinstance(spec.get("type"), str) else "?"
    ins = []
    for p, ref in _dict(spec.get("inputs")).items():
        for r in (ref if isinstance(ref, list) else [ref]):
            if isinstance(r, str) and "." in r:
                s, _, sp = r.rpartition(".")
                ins.append([p, s, sp])
    outs = {}
    with contextlib.suppress(Exception):
        outs = {p: port.type.name for p, port in registry.node_class(typ).out_ports.items()}
    return typ, ins, outs, _dict(spec.get("params")), sorted({s for _, s, _ in ins})


def _add_schema(studio, typ: str, schemas: dict, defs: dict) -> None:
    """The params schema of node type ``typ`` into ``schemas`` (its $defs into ``defs``)."""
    from ..schema import node_schema

    if typ in schemas or typ not in studio.registry.nodes:
        return
    cache = studio.schema_cache
    if typ not in cache:  # pydantic's schema of a type never changes
        cache[typ] = None
        with contextlib.suppress(Exception):
            s, d = node_schema(studio.registry, typ)
            cache[typ] = ({"params": s["properties"]["params"], "description": s["description"]}, d)
    if cache[typ] is not None:
        schemas[typ] = cache[typ][0]
        defs.update(cache[typ][1])


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


def _manifest_summary(m: dict | None):
    if not m:
        return None
    return {"finished": m.get("finished"), "nodes": {n: {"hit": v.get("hit"), "seconds": v.get("seconds")}
                                                     for n, v in (m.get("nodes") or {}).items()}}


_PARAM_REF = re.compile(r"^\s*\$\{params\.([A-Za-z_][A-Za-z0-9_]*)\}\s*$")


def _graph_param_schemas(raw_nodes: dict, schemas: dict, defs: dict) -> dict:
    """A graph param takes the schema of the first node param that is exactly it."""
    out: dict[str, dict] = {}

    def walk(v, sch, where):
        if isinstance(v, str):
            m = _PARAM_REF.match(v)
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


def _default_preview(g):
    """The output a page shows first: a contact sheet, else the first image output (or the
    image a File writer writes), else any image."""
    if g is None:
        return None
    outs = sorted(g.outputs.items(), key=lambda kv: "sheet" not in kv[0].lower())  # contact sheets first
    for _, (node, port) in outs:
        found = _image_of_output(g, node, port)
        if found:
            return found
    for n, gn in g.nodes.items():
        for p, port in gn.cls.out_ports.items():
            if port.type.name in PREVIEWABLE:
                return [n, p]
    return None


def _image_of_output(g, node: str, port: str):
    if g.nodes[node].cls.out_ports[port].type.name in PREVIEWABLE:
        return [node, port]
    for _, src, sport in g.nodes[node].edges():  # a File writer: preview what it writes
        if g.nodes[src].cls.out_ports[sport].type.name in PREVIEWABLE:
            return [src, sport]
    return None
