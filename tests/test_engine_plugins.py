"""Plugins: entry-point discovery, duplicate names, broken plugins, the JSON Schema, `nodes`."""
import json
import textwrap

import jsonschema
import pytest
import yaml

from conftest import ROOT, engine_env, graphkit


def plugin_env(tmp_path, *modules):
    env = engine_env()
    env["PYTHONPATH"] = f"{tmp_path}:{env['PYTHONPATH']}"
    env["GRAPHKIT_PLUGINS"] = ",".join(modules)
    return env


def test_builtin_nodes_registered_by_entry_point():
    from importlib.metadata import entry_points

    eps = {ep.name: ep.value for ep in entry_points(group="graphkit.nodes")}
    assert eps.get("io") == "nodes.io:NODES" and eps.get("paris") == "nodes.paris:NODES"
    import graphkit.registry as R
    src = open(R.__file__).read() + "".join(open(p).read() for p in (ROOT / "graphkit").glob("*.py"))
    assert "import nodes" not in src and "from nodes" not in src  # the engine never imports nodes


def test_duplicate_node_name_names_both_providers(tmp_path, write):
    (tmp_path / "dupe.py").write_text(textwrap.dedent('''
        from graphkit import Node, Array
        class Const(Node):
            """another Const"""
            outputs = {"out": Array}
            def compute(self):
                return 0
    '''))
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n")
    r = graphkit("validate", g, env=plugin_env(tmp_path, "enginenodes", "dupe"))
    assert r.returncode == 2
    assert "node type 'Const' is provided twice" in r.stderr
    assert "enginenodes" in r.stderr and "dupe" in r.stderr
    assert "Traceback" not in r.stderr


def test_broken_plugin_is_reported_and_the_rest_load(tmp_path, write):
    (tmp_path / "broken.py").write_text("raise ImportError('needs libfoo')\n")
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o",
                 env=plugin_env(tmp_path, "broken", "enginenodes"))
    assert r.returncode == 0, r.stderr
    assert "'broken' failed to import: ImportError: needs libfoo" in r.stderr


def test_nodes_command_describes_a_node():
    r = graphkit("nodes", "RatioImage")
    assert r.returncode == 0
    assert "Paris 2003 §3" in r.stdout and "eps" in r.stdout and "numpy" in r.stdout
    r = graphkit("nodes", "RatioImag")
    assert r.returncode == 2 and "did you mean 'RatioImage'" in r.stderr


def test_schema_accepts_repo_graphs_and_rejects_bad_ones(tmp_path):
    r = graphkit("schema", "-o", tmp_path / "schema.json")
    assert r.returncode == 0, r.stderr
    schema = json.loads((tmp_path / "schema.json").read_text())
    graphs = sorted((ROOT / "graphs").glob("*.yaml"))
    assert graphs
    for g in graphs:
        jsonschema.validate(yaml.safe_load(g.read_text()), schema)
    bad = {"graphkit": 1, "nodes": {"r": {"type": "RatioImage", "params": {"eps": -1}}}}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)
    bad = {"graphkit": 1, "nodes": {"r": {"type": "RatioImage", "params": {"epsilon": 1}}}}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)


def test_show_formats(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n  d: {type: Add, inputs: {a: c.out}}\n")
    r = graphkit("show", g)
    assert r.returncode == 0 and "flowchart LR" in r.stdout and "c -->|out→a| d" in r.stdout
    r = graphkit("show", g, "--format", "dot")
    assert '"c" -> "d"' in r.stdout
