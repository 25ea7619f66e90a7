"""run_local(first=...) and Session(on_outputs=...): the two hooks the studio's slider path uses.

- ``first``: the nodes asked for first run, with what they need, before the rest of the graph
  (still in a topological order, and every node still runs once).
- ``on_outputs`` (every value here distinct, so none is stored before its node runs): called once a computed node's outputs are checked and hashed, before they
  are stored: at that moment neither the record nor the objects are in the store; after the
  run both are, with the digests the hook saw; a cache hit does not call it.
"""
from __future__ import annotations

import pytest

from graphkit.executor import Progress, run_local
from graphkit.graphfile import load_graph
from graphkit.runner import Session
from graphkit.store import Store

GRAPH = """\
graphkit: 1
name: order
nodes:
  a: {type: Const, params: {value: 1.0}}
  b: {type: Const, params: {value: 2.0}}
  c: {type: Const, params: {value: 5.0}}
  ab: {type: Add, inputs: {a: a.out, b: b.out}}
  bc: {type: Add, inputs: {a: b.out, b: c.out}}
  last: {type: Add, inputs: {a: bc.out}, params: {offset: 0.5}}
outputs: {ab: ab.out, last: last.out}
"""


class Order(Progress):
    def __init__(self):
        self.seen = []

    def running(self, node, node_type):
        self.seen.append(node)


@pytest.fixture
def graph(write, engine_registry):
    return load_graph(write("g.yaml", GRAPH), engine_registry), engine_registry


def test_first_runs_what_it_needs_before_the_rest(graph, tmp_path):
    g, reg = graph
    plain = Order()
    run_local(Session(g, reg, Store(tmp_path / "c1").open()), ["ab", "last"], progress=plain)
    early = Order()
    res = run_local(Session(g, reg, Store(tmp_path / "c2").open()), ["ab", "last"], progress=early, first=["last"])
    assert plain.seen.index("ab") < plain.seen.index("last")  # the usual order: last comes late
    assert set(early.seen[:4]) == {"b", "c", "bc", "last"}, early.seen  # last and what it needs first
    assert sorted(early.seen) == sorted(plain.seen) == sorted(res.outcomes)  # each node once
    for n in early.seen:  # still topological
        assert all(early.seen.index(s) < early.seen.index(n) for s in g.nodes[n].sources())
    # a node that the targets do not need is ignored, not run
    other = Order()
    run_local(Session(g, reg, Store(tmp_path / "c3").open()), ["ab"], progress=other, first=["last"])
    assert sorted(other.seen) == ["a", "ab", "b"]


def test_on_outputs_comes_before_the_store_writes(graph, tmp_path):
    g, reg = graph
    store = Store(tmp_path / "c").open()
    calls = []

    def hook(node, digests, values):
        key, _ = session.key(g.nodes[node], {p: session._outcomes[s].outputs[sp]
                                             for p, s, sp in g.nodes[node].edges()})
        calls.append((node, dict(digests), {p: v.copy() for p, v in values.items()},
                      store.get_record(key) is None,
                      all(not store.fs.exists(store.object_rel(d)) for d in digests.values())))

    session = Session(g, reg, store, on_outputs=hook)
    res = run_local(session, ["ab", "last"])
    assert sorted(c[0] for c in calls) == sorted(res.outcomes)
    for node, digests, values, no_record, no_objects in calls:
        assert no_record and no_objects, f"{node}: stored before on_outputs"
        o = res.outcomes[node]
        assert digests == o.outputs  # the digests the record names
        assert store.get_record(o.key) is not None
        for p, d in digests.items():  # the values it saw are the stored ones
            assert (store.load_value(d) == values[p]).all()
    calls.clear()
    run_local(Session(g, reg, store, on_outputs=hook), ["ab", "last"])  # all hits
    assert calls == []
