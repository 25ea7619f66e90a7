"""Issue 25: graphs of any depth and size.  Nothing in the engine recurses over the graph's
depth (before, a chain of 250 nodes was refused: the recipe digest recursed node by node), so a
10 000-node chain and a 20 000-node fan-out load, validate, dry-run, run cold and warm, draw in
`graphkit show` and open in the studio, all at Python's default recursion limit."""
import sys

import pytest

from graphkit import run_graph
from graphkit.dryrun import status
from graphkit.graphfile import load_graph
from graphkit.show import draw


def chain(n: int) -> str:
    """n nodes, each reading the one before; written last first, so that walking the graph in
    the file's order starts at its deepest node."""
    nodes = [f"  n{i}: {{type: Noop, inputs: {{x: n{i - 1}.out}}, params: {{i: {i}}}}}" for i in range(n - 1, 0, -1)]
    lines = ["graphkit: 1", "name: chain", "nodes:", *nodes, "  n0: {type: Const, params: {size: 4}}"]
    return "\n".join(lines + [f"outputs: {{last: n{n - 1}.out}}"]) + "\n"


def fan_out(n: int) -> str:
    """One source, n - 2 nodes reading it, one node summing them all."""
    lines = ["graphkit: 1", "name: fan", "nodes:", "  src: {type: Const, params: {size: 4}}"]
    lines += [f"  n{i}: {{type: Noop, inputs: {{x: src.out}}, params: {{i: {i}}}}}" for i in range(1, n - 1)]
    lines.append("  sink: {type: Sum, inputs: {xs: [" + ", ".join(f"n{i}.out" for i in range(1, n - 1)) + "]}}")
    return "\n".join(lines + ["outputs: {sum: sink.out, count: sink.count}"]) + "\n"


@pytest.mark.parametrize("make, n, last", [(chain, 10_000, "n9999"), (fan_out, 20_000, "sink")], ids=["chain", "fan-out"])
def test_large_graphs_run_end_to_end(tmp_path, write, engine_registry, make, n, last):
    from graphkit.studio.core import Studio

    assert sys.getrecursionlimit() < n / 2  # far less deep than the chain: no recursion over it
    g = write("g.yaml", make(n))
    graph = load_graph(g, engine_registry, {})  # what `graphkit validate` does
    assert len(graph.nodes) == n and graph.order()[-1] == last
    cache, out = tmp_path / "c", tmp_path / "o"
    before = status(graph, cache, registry=engine_registry)  # dry-run
    assert len(before.would_run) == n
    cold = run_graph(graph, cache=cache, out=out, registry=engine_registry)
    assert len(cold.computed) == n and (out / "manifest.json").exists()
    warm = run_graph(graph, cache=cache, out=out, registry=engine_registry)
    assert len(warm.cached) == n and not warm.computed
    assert draw(graph).count("-->") == (n - 1 if make is chain else 2 * (n - 2))
    if make is chain:  # the studio lays the graph out by depth (it recursed, one level a node)
        st = Studio(g, cache=str(cache), out=None, registry=engine_registry, autorun=False)
        try:
            state = st.state()
        finally:
            st.close()
        assert state["graph"]["valid"], state["errors"]
        assert {nd["name"]: nd["layer"] for nd in state["nodes"]}[last] == n - 1


def test_studio_parses_a_graph_once(tmp_path, write, engine_registry, monkeypatch):
    """Opening a graph in the studio parses its text once: the document it shows and the graph
    it validates share that parse; a problem is still placed in the graph file."""
    import graphkit.graphfile as gf
    from graphkit.studio.core import Studio

    parses = []
    real = gf.parse_yaml
    monkeypatch.setattr(gf, "parse_yaml", lambda text, file: parses.append(file) or real(text, file))
    for text, valid in ((chain(50), True), (chain(50) + "name: again\n", False)):  # (a duplicate key)
        parses.clear()
        g = write("g.yaml", text)
        st = Studio(g, cache=str(tmp_path / "c"), out=None, registry=engine_registry, autorun=False)
        try:
            state = st.state()
        finally:
            st.close()
        assert state["graph"]["valid"] is valid and len(parses) == 1, (state["errors"], parses)
        assert valid or state["errors"][0]["file"] == str(g), state["errors"]
