"""`graphkit show`: the graph as a mermaid flowchart or a Graphviz DOT digraph.

A swept node is drawn once, as ``NAME ×N`` (``instances=True`` draws every instance).  Given a
:class:`graphkit.dryrun.StatusReport`, nodes are coloured by what a run would do: green
cached, orange would run, yellow some instances of a swept node would run.
"""
from __future__ import annotations

import re

from .model import Graph

COLOURS = {"cached": ("#d8f0d8", "#2e7d32"), "run": ("#ffe3bf", "#e65100"), "partial": ("#fff5b8", "#a68b00")}


def _boxes(graph: Graph, instances: bool):
    """[(id, name, type, count, sweep, members)] and [(src id, dst id, label)]."""
    if instances:
        ids = _ids(list(graph.nodes))
        boxes = [(ids[n], n, g.type, 1, None, [n]) for n, g in graph.nodes.items()]
        edges = [(ids[src], ids[n], f"{sport}→{port}") for n, g in graph.nodes.items()
                 for port, src, sport in g.edges()]
        return boxes, edges
    members: dict[str, list[str]] = {}
    for n, g in graph.nodes.items():
        members.setdefault(g.base or n, []).append(n)
    ids = _ids(list(members))
    boxes = []
    for base, ms in members.items():
        g = graph.nodes[ms[0]]
        boxes.append((ids[base], base, g.type, len(ms) if g.sweep else 1, g.sweep, ms))
    return boxes, _swept_edges(graph, members, ids)


def _swept_edges(graph: Graph, members: dict[str, list[str]], ids: dict[str, str]) -> list[tuple]:
    """The edges between swept nodes drawn once each (a gather of all instances: ``[*]``)."""
    edges, seen = [], set()
    for base, ms in members.items():
        dst = graph.nodes[ms[0]]
        for port, src, sport in dst.edges():
            sg = graph.nodes[src]
            sb = sg.base or src
            gather = sg.sweep is not None and sg.sweep != dst.sweep
            label = f"{sport}→{port}" + (" [*]" if gather else "")
            e = (ids[sb], ids[base], label)
            if e not in seen:
                seen.add(e)
                edges.append(e)
    return edges


def _ids(names: list[str]) -> dict[str, str]:
    out, used = {}, set()
    for n in names:
        i = n if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_\-]*", n) else re.sub(r"[^A-Za-z0-9_]", "_", n)
        while i in used:
            i += "_"
        used.add(i)
        out[n] = i
    return out


def _state(report, members: list[str]) -> tuple[str, str] | None:
    if report is None:
        return None
    states = [report.nodes[m].state for m in members if m in report.nodes]
    if not states:
        return None
    run = sum(s != "cached" for s in states)
    if run == 0:
        return "cached", "cached"
    if run == len(states):
        return "run", "would run"
    return "partial", f"{run}/{len(states)} would run"


def draw(graph: Graph, fmt: str = "mermaid", report=None, instances: bool = False) -> str:
    boxes, edges = _boxes(graph, instances)
    return (_draw_dot if fmt == "dot" else _draw_mermaid)(graph, boxes, edges, report)


def _labels(name: str, typ: str, count: int, sweep) -> tuple[str, str]:
    """A box's title and subtitle."""
    title = f"{name} ×{count}" if count > 1 else name
    sub = typ + (f" · foreach {sweep}" if sweep and count > 1 else "")
    return title, sub


def _draw_dot(graph: Graph, boxes, edges, report) -> str:
    lines = [f'digraph "{graph.name}" {{', "  rankdir=LR;", "  node [shape=box];"]
    for bid, name, typ, count, sweep, ms in boxes:
        title, sub = _labels(name, typ, count, sweep)
        st = _state(report, ms)
        label = "\\n".join(_dot(x) for x in (title, sub, st[1] if st else None) if x)
        extra = ""
        if st:
            fill, line = COLOURS[st[0]]
            extra = f' style=filled fillcolor="{fill}" color="{line}"'
        lines.append(f'  "{bid}" [label="{label}"{extra}];')
    for s, d, label in edges:
        lines.append(f'  "{s}" -> "{d}" [label="{_dot(label)}"];')
    lines.append("}")
    return "\n".join(lines)


def _draw_mermaid(graph: Graph, boxes, edges, report) -> str:
    lines = ["flowchart LR"]
    classes: dict[str, list[str]] = {}
    for bid, name, typ, count, sweep, ms in boxes:
        title, sub = _labels(name, typ, count, sweep)
        st = _state(report, ms)
        if st:
            classes.setdefault(st[0], []).append(bid)
            sub += f" · {st[1]}"
        lines.append(f'  {bid}["{_md(title)}<br/><small>{_md(sub)}</small>"]')
    for s, d, label in edges:
        lines.append(f"  {s} -->|{_md(label)}| {d}")
    for cls, ids in classes.items():
        fill, line = COLOURS[cls]
        lines.append(f"  classDef {cls} fill:{fill},stroke:{line}")
        lines.append(f"  class {','.join(ids)} {cls}")
    return "\n".join(lines)


def _dot(s: str) -> str:
    return s.replace("\\", "\\\\").replace('"', '\\"')


def _md(s: str) -> str:
    return s.replace('"', "#quot;").replace("|", "#124;")


__all__ = ["draw"]
