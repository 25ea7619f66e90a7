"""`graphkit explain GRAPH NODE`: which part of a node's cache key changed since the last run."""
from __future__ import annotations

from .executor import graph_id
from .model import Graph
from .runner import Session
from .store import Store
from .errors import UsageError


def explain(graph: Graph, store: Store, node: str, registry=None) -> str:
    from .registry import default_registry
    from .dryrun import CACHED, walk

    _check_node(graph, node)
    session = Session(graph, registry or default_registry(), store)
    last = store.last_run(graph_id(graph)) or {}
    state = {n: {"key": st.key, "cached": st.state == CACHED, "parts": st.parts,
                 "waits": [r.message for r in st.reasons if r.part == "upstream"]}
             for n, st in walk(session, graph.upstream([node])).items()}
    s, typ = state[node], graph.nodes[node].type
    if s["cached"]:
        lines = [f"{node} ({typ}) is cached: a run would not recompute it (key {s['key'][:16]})."]
    else:
        lines = [f"{node} ({typ}) would be computed."]
    prev = last.get(node)
    if prev is None:
        lines.append("  no earlier run of this graph recorded for it in this cache.")
    elif s["key"] == prev["key"]:
        lines.append("  its key is the same as at the last run.")
    else:
        if s["parts"] is None:
            lines.append(f"  its inputs are not known yet: {s['waits'][0]}.")
        else:
            lines.extend(_diff(s["parts"], prev["parts"], graph, node))
        lines.extend(_upstream_changes(graph, node, last, state))
    return "\n".join(lines)


def _check_node(graph: Graph, node: str) -> None:
    """UsageError unless ``node`` is one node of the graph (a swept node's base is not)."""
    from .suggest import did_you_mean

    if node in graph.nodes:
        return
    inst = graph.instances(node)
    if inst:
        raise UsageError(f"'{node}' is swept ({len(inst)} instances): explain one of them, e.g. "
                         f"'{inst[0]}'")
    raise UsageError(f"no node named '{node}' in {graph.path}{did_you_mean(node, graph.nodes)}")


def _upstream_changes(graph: Graph, node: str, last: dict, state: dict) -> list[str]:
    """The upstream nodes whose own key parts changed since the last run (the root causes)."""
    lines = []
    for n in graph.upstream([node])[:-1]:
        p, cur = last.get(n), state[n]
        if p is None or cur["parts"] is None:
            continue
        own = {k: v for k, v in cur["parts"].items() if k != "inputs"}
        own_prev = {k: v for k, v in p["parts"].items() if k != "inputs"}
        if own != own_prev:
            lines.append(f"  upstream {n} ({graph.nodes[n].type}) changed:")
            lines.extend("  " + x for x in _diff(cur["parts"], p["parts"], graph, n, inputs=False))
    return lines


def _diff(cur: dict, prev: dict, graph: Graph, node: str, inputs: bool = True) -> list[str]:
    from .dryrun import _flat

    a, b = _flat(cur), _flat(prev)
    out = []
    for k in sorted(set(a) | set(b)):
        if not inputs and k.startswith("inputs."):
            continue
        if a.get(k, "<absent>") != b.get(k, "<absent>"):
            if k.startswith("inputs."):
                port = k.split(".", 1)[1]
                srcs = [f"{s}.{sp}" for p, s, sp in graph.nodes[node].edges() if p == port] or ["?"]
                out.append(f"  input '{port}' changed (from {', '.join(srcs)}): "
                           f"{str(b.get(k))[:12]} → {str(a.get(k))[:12]}")
            else:
                out.append(f"  {k}: {b.get(k, '<absent>')!r} → {a.get(k, '<absent>')!r}")
    return out
