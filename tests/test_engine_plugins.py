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


def test_a_ctrl_c_during_a_plugins_import_is_not_a_broken_plugin(tmp_path, write):
    """A Ctrl-C that lands while a class body of the plugin is set up reaches the registry as a
    RuntimeError on Python 3.11 ("Error calling __set_name__"); it used to be reported as a broken
    plugin, skipped, and the run went on.  Now the run ends as interrupted: exit 130."""
    (tmp_path / "slow.py").write_text(textwrap.dedent("""
        class Field:
            def __set_name__(self, owner, name):
                raise KeyboardInterrupt  # what a SIGINT here looks like
        class Model:
            validators = Field()
    """))
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o",
                 env=plugin_env(tmp_path, "slow", "enginenodes"))
    assert r.returncode == 130, r.stderr
    assert r.stderr.strip() == "graphkit: interrupted" and not (tmp_path / "o").exists(), r.stderr


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


# --------------------------------------------------------------------------------------------
# declared contract: port types by qualified name, type_name = key, hooks and studio views


TWO_IMAGES = {
    "pluga.py": '''
        from pydantic import BaseModel
        from graphkit import Node
        class Image(BaseModel):
            """pluga's image"""
            w: int = 1
        class MakeA(Node):
            outputs = {"out": Image}
            def compute(self):
                return Image()
        class TakeA(Node):
            inputs = {"x": Image}
            outputs = {"out": Image}
            def compute(self, x):
                return x
    ''',
    "plugb.py": '''
        from pydantic import BaseModel
        from graphkit import Node
        class Image(BaseModel):
            """plugb's image"""
            h: int = 1
        class TakeB(Node):
            inputs = {"x": Image}
            outputs = {"out": Image}
            def compute(self, x):
                return x
    ''',
}


def test_two_plugins_port_types_of_the_same_name_do_not_collide(tmp_path, write):
    for name, src in TWO_IMAGES.items():
        (tmp_path / name).write_text(textwrap.dedent(src))
    env = plugin_env(tmp_path, "pluga", "plugb")
    ok = write("ok.yaml", "graphkit: 1\nnodes:\n  m: {type: MakeA}\n  t: {type: TakeA, inputs: {x: m.out}}\n")
    r = graphkit("validate", ok, env=env)
    assert r.returncode == 0, r.stderr
    bad = write("bad.yaml", "graphkit: 1\nnodes:\n  m: {type: MakeA}\n  t: {type: TakeB, inputs: {x: m.out}}\n")
    r = graphkit("validate", bad, env=env)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "node 't', input 'x' takes plugb.Image but m.out gives pluga.Image" in r.stderr, r.stderr
    # a builtin Image is neither (the short name stays what users see where it is unambiguous)
    r = graphkit("nodes", "TakeA", env=env)
    assert "  x: Image  " in r.stdout


def test_registry_refuses_a_type_name_that_differs_from_its_key(tmp_path, write):
    (tmp_path / "misnamed.py").write_text(textwrap.dedent('''
        from graphkit import Array, Node
        NODES = {"Shiny": "misnamed:Dull"}
        class Dull(Node):
            outputs = {"out": Array}
            def compute(self):
                return 0
    '''))
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Shiny}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o", env=plugin_env(tmp_path, "misnamed"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert ("plugin 'GRAPHKIT_PLUGINS:misnamed' (misnamed:Dull) registers node type 'Shiny', but the class's "
            "type_name is 'Dull'") in r.stderr, r.stderr


def test_hooks_and_studio_view_are_declared_and_listed():
    from graphkit import Image, Node

    def make(**attrs):
        return type("N", (Node,), {"outputs": {"o": Image}, "compute": lambda self: None, **attrs})

    make(hooks=("blur",), blur=staticmethod(lambda x: x), studio_view="pkg.views:View")
    with pytest.raises(TypeError, match="N.hooks names 'blur', which is not a staticmethod of N"):
        make(hooks=("blur",), blur=lambda self, x: x)
    with pytest.raises(TypeError, match="N.hooks must be a tuple of names"):
        make(hooks="blur", blur=staticmethod(lambda x: x))
    with pytest.raises(TypeError, match='N.studio_view must be a "module:Class" string'):
        make(studio_view="pkg.views.View")
    r = graphkit("nodes", "KMStack")
    assert "hooks (a backend may replace): pixel_stack, stack_over_rgb" in r.stdout
    assert "studio view: nodes.huang.studio_view:MakeupView" in r.stdout
    rows = json.loads(graphkit("nodes", "--json").stdout)
    by = {r["type"]: r for r in rows}
    assert by["Relight"]["hooks"] == ["modulate_pixels"] and by["RatioImage"]["hooks"] == []
    assert by["Relight"]["studio_view"] == "nodes.loscos.studio_view:RoomView"
    assert by["RatioImage"]["inputs"]["b"]["constraints"] == {"same_size_as": "a"}


def test_nodes_and_schema_show_port_constraints(tmp_path):
    r = graphkit("nodes", "KMStack")
    assert ("  background: Image (optional)  linear-RGB reflectance under the layers (e.g. skin albedo)  "
            "[needs: 3 channels; finite (no NaN or Inf); values ≥ 0; values ≤ 1]") in r.stdout, r.stdout
    r = graphkit("schema", "-o", tmp_path / "schema.json")
    schema = json.loads((tmp_path / "schema.json").read_text())
    ratio = next(v["then"] for v in schema["properties"]["nodes"]["additionalProperties"]["allOf"]
                 if v["if"]["properties"]["type"]["const"] == "RatioImage")
    b = ratio["properties"]["inputs"]["properties"]["b"]
    assert b["x-constraints"] == {"same_size_as": "a"} and "(needs: same width and height as 'a')" in b["description"]


def test_an_opencl_backend_may_replace_only_declared_hooks():
    from graphkit_opencl.base import OpenCLBackend

    class Sneaky(OpenCLBackend):
        node = "KMStack"

        @classmethod
        def hooks(cls):
            return {"pixel_stack": lambda *a: None, "resolve_layers": lambda *a: None}

    with pytest.raises(TypeError, match="Sneaky: node type KMStack declares no hook 'resolve_layers' "
                                        r"\(its hooks: pixel_stack, stack_over_rgb\)"):
        Sneaky.accelerated()
