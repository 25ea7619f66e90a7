"""Caching: a second run computes nothing, a param change re-runs only what depends on it,
early cutoff stops at identical bytes, explain names the changed part."""
import numpy as np

from graphkit import run_graph

CHAIN = """\
graphkit: 1
name: chain
params: {v: 1.0, off: 0.0, label: x}
nodes:
  a: {type: Const, params: {value: "${params.v}", label: "${params.label}"}}
  b: {type: Const, params: {value: 10.0}}
  c: {type: Add, inputs: {a: a.out, b: b.out}}
  d: {type: Add, inputs: {a: c.out}, params: {offset: "${params.off}"}}
  e: {type: Add, inputs: {a: b.out}, params: {offset: 5}}
  s: {type: Sum, inputs: {xs: [d.out, e.out, a.out]}}
outputs: {s: s.out, e: e.out, n: s.count}
"""


def run(path, cache, reg, **over):
    return run_graph(path, cache=cache, overrides=over, registry=reg, jobs=2)


def test_second_run_computes_nothing(tmp_path, write, engine_registry):
    g = write("chain.yaml", CHAIN)
    first = run(g, tmp_path / "c", engine_registry)
    assert sorted(first.computed) == ["a", "b", "c", "d", "e", "s"]
    np.testing.assert_array_equal(first.value("s"), np.full(4, 11.0 + 15.0 + 1.0))
    assert first.value("n") == 3.0
    second = run(g, tmp_path / "c", engine_registry)
    assert second.computed == []
    assert sorted(second.cached) == ["a", "b", "c", "d", "e", "s"]
    np.testing.assert_array_equal(second.value("s"), first.value("s"))


def test_param_change_reruns_only_downstream(tmp_path, write, engine_registry):
    g = write("chain.yaml", CHAIN)
    run(g, tmp_path / "c", engine_registry)
    r = run(g, tmp_path / "c", engine_registry, off=2.0)
    assert sorted(r.computed) == ["d", "s"]  # not a, b, c, e
    np.testing.assert_array_equal(r.value("s"), np.full(4, 13.0 + 15.0 + 1.0))
    r = run(g, tmp_path / "c", engine_registry, v=3.0)
    assert sorted(r.computed) == ["a", "c", "d", "s"]


def test_early_cutoff(tmp_path, write, engine_registry):
    """`label` changes a's key but not its bytes: a re-runs, nothing downstream does."""
    g = write("chain.yaml", CHAIN)
    run(g, tmp_path / "c", engine_registry)
    r = run(g, tmp_path / "c", engine_registry, label="other")
    assert r.computed == ["a"]


def test_outputs_select_what_runs(tmp_path, write, engine_registry):
    g = write("chain.yaml", CHAIN)
    r = run_graph(g, cache=tmp_path / "c", registry=engine_registry, outputs=["e"])
    assert sorted(r.computed) == ["b", "e"]


def test_explain_names_the_changed_part(tmp_path, write, engine_registry):
    from graphkit.explain import explain
    from graphkit.graphfile import load_graph
    from graphkit.store import Store

    g = write("chain.yaml", CHAIN)
    run(g, tmp_path / "c", engine_registry)
    store = Store(tmp_path / "c").open()
    text = explain(load_graph(g, engine_registry, {}), store, "d", engine_registry)
    assert "is cached" in text and "same as at the last run" in text
    text = explain(load_graph(g, engine_registry, {"off": 7.0}), store, "d", engine_registry)
    assert "would be computed" in text and "params.offset: 0.0 → 7.0" in text
    text = explain(load_graph(g, engine_registry, {"v": 2.0}), store, "c", engine_registry)
    assert "upstream a (Const) changed" in text and "params.value: 1.0 → 2.0" in text


def test_same_bytes_in_another_cache(tmp_path, write, engine_registry):
    g = write("chain.yaml", CHAIN)
    r1 = run(g, tmp_path / "c1", engine_registry)
    r2 = run_graph(g, cache=tmp_path / "c2", registry=engine_registry, jobs=1)
    k1 = {n: (o.key, o.outputs) for n, o in r1.result.outcomes.items()}
    k2 = {n: (o.key, o.outputs) for n, o in r2.result.outcomes.items()}
    assert k1 == k2

