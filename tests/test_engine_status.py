"""Dry runs: per node instance "cached" or "would run", with the key part that changed (like
Snakemake's reasons), without running or writing anything; `show --status` colours the DAG."""
import numpy as np
import pytest

from conftest import engine_env, graphkit
from graphkit import run_graph
from graphkit.dryrun import CACHED, WOULD_RUN, status

G = """\
graphkit: 1
name: st
params: {v: 1.0, off: 0.0, vals: [1, 2, 3, 4]}
sweeps:
  k: {values: "${params.vals}", name: "k{index}"}
nodes:
  img: {type: LoadImage, params: {path: pic.exr}}
  m: {type: ImageMean, inputs: {image: img.image}}
  a: {type: Const, params: {value: "${params.v}"}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: "${params.off}"}}
  n: {type: Noop, inputs: {x: b.out}}
  each: {type: Add, foreach: k, inputs: {a: n.out}, params: {offset: "${k.value}"}}
  all: {type: Sum, inputs: {xs: "each[*].out"}}
outputs: {m: m.out, all: all.out}
"""


@pytest.fixture
def reg(engine_registry):
    import sweepnodes

    engine_registry.add_provider("nodes", "tests", sweepnodes)
    engine_registry.add_provider("backends", "tests", sweepnodes)
    return engine_registry


def write_exr(path, value):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(4, 3, 3, "float"))
    out.write_image(np.full((3, 4, 3), value, np.float32))
    out.close()


def parts(report, node):
    s = report.nodes[node]
    return s.state, [r.part for r in s.reasons], "; ".join(r.message for r in s.reasons)


def test_reasons_for_each_key_part(tmp_path, write, reg, monkeypatch):
    g = write("st.yaml", G)
    write_exr(tmp_path / "pic.exr", 0.25)
    cache = tmp_path / "cache"

    fresh = status(g, cache, registry=reg)
    assert set(fresh.would_run) == set(fresh.graph.nodes) and not fresh.cached
    assert parts(fresh, "a") == (WOULD_RUN, ["new"], "not computed before")
    assert parts(fresh, "b")[1] == ["upstream"] and "upstream a would run first" in parts(fresh, "b")[2]
    assert not cache.exists()  # a dry run writes nothing, not even the cache folder

    run_graph(g, cache=cache, registry=reg)
    same = status(g, cache, registry=reg)
    assert same.would_run == [] and all(s.state == CACHED for s in same.nodes.values())

    # a param
    r = status(g, cache, registry=reg, overrides={"off": 2.5})
    assert parts(r, "b") == (WOULD_RUN, ["params"], "param changed: offset 0.0 → 2.5")
    assert parts(r, "a")[0] == CACHED
    assert parts(r, "n")[1] == ["upstream"]

    # one instance of a sweep: only it
    r = status(g, cache, registry=reg, overrides={"vals": [1, 2, 30, 4]})
    assert r.would_run == ["each[k2]", "all"]
    assert parts(r, "each[k2]") == (WOULD_RUN, ["params"], "param changed: offset 3.0 → 30.0")

    # an input file's content
    write_exr(tmp_path / "pic.exr", 0.5)
    r = status(g, cache, registry=reg)
    assert parts(r, "img") == (WOULD_RUN, ["input-file"], "input file changed: path (pic.exr)")
    assert r.would_run == ["img", "m"]
    write_exr(tmp_path / "pic.exr", 0.25)

    # the node's version
    from enginenodes import Noop

    monkeypatch.setattr(Noop, "version", "2")
    r = status(g, cache, registry=reg)
    assert parts(r, "n") == (WOULD_RUN, ["node-version"], "node version 1 → 2")
    monkeypatch.setattr(Noop, "version", "1")

    # the backend
    r = status(g, cache, registry=reg, backends=["alt"])
    assert parts(r, "n") == (WOULD_RUN, ["backend"], "backend numpy 1 → alt 1")
    assert r.nodes["n"].backend == "alt"

    # an upstream value: a is cached with another value (from an earlier run), b's input differs
    run_graph(g, cache=cache, registry=reg, overrides={"v": 5.0}, outputs=["m"])  # nothing of a's
    run_graph(g, cache=cache, registry=reg, overrides={"v": 5.0})
    run_graph(g, cache=cache, registry=reg)  # last run: v = 1
    r = status(g, cache, registry=reg, overrides={"v": 5.0})
    assert parts(r, "a")[0] == CACHED and parts(r, "b")[0] == CACHED  # both ran with v=5 before
    from graphkit.store import Store

    store = Store(cache).open()
    store.fs.remove(store.record_rel(r.nodes["b"].key))  # gone: gc or verify --repair
    r = status(g, cache, registry=reg, overrides={"v": 5.0})
    assert parts(r, "b") == (WOULD_RUN, ["inputs"], "input changed: 'a' (from a.out)")
    r = status(g, cache, registry=reg)
    assert parts(r, "b")[0] == CACHED
    store.fs.remove(store.record_rel(r.nodes["b"].key))
    r = status(g, cache, registry=reg)
    assert parts(r, "b")[1] == ["missing"]


def test_dry_run_and_show_status_cli(tmp_path, write):
    g = write("st.yaml", G)
    write_exr(tmp_path / "pic.exr", 0.25)
    env = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,sweepnodes"})
    cache, out = tmp_path / "cache", tmp_path / "out"
    r = graphkit("run", g, "--cache", cache, "--out", out, env=env)
    assert r.returncode == 0, r.stderr
    before = sorted(p.name for p in cache.glob("keys/*/*.json"))
    (out / "manifest.json").unlink()
    r = graphkit("run", g, "--cache", cache, "--out", out, "--dry-run", "--set", "vals=[1, 2, 3, 40]", env=env)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert any(line.split()[:3] == ["would", "run", "each[k3]"] and "param changed: offset 4.0 → 40.0" in line
               for line in lines), r.stdout
    assert any(line.split()[:2] == ["cached", "each[k0]"] for line in lines), r.stdout
    assert lines[-1] == "st: 2 would run, 8 cached (dry run: nothing was run)"
    assert sorted(p.name for p in cache.glob("keys/*/*.json")) == before and not (out / "manifest.json").exists()
    r = graphkit("status", g, "--cache", cache, "--json", env=env)
    import json

    data = json.loads(r.stdout)
    assert data["counts"] == {"cached": 10, "would run": 0}
    r = graphkit("show", g, "--cache", cache, "--status", "--set", "vals=[1, 2, 3, 40]", env=env)
    assert r.returncode == 0, r.stderr
    assert 'each["each ×4<br/><small>Add · foreach k · 1/4 would run</small>"]' in r.stdout, r.stdout
    assert "class img,m,a,b,n cached" in r.stdout and "class each partial" in r.stdout and "class all run" in r.stdout
    assert "each -->|out→xs [*]| all" in r.stdout
    r = graphkit("show", g, "--format", "dot", "--instances", env=env)
    assert '"each_k3_" -> "all"' in r.stdout, r.stdout
