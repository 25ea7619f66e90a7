"""Sweeps and batches: a node or sub-graph instantiated over values, a matrix or a file glob; each
instance an ordinary cached node; fan-in ports take every instance in order; bad sweeps are
located errors (exit 2) and nothing runs."""
import json
import re

import numpy as np
import pytest

from conftest import engine_env, graphkit
from graphkit import run_graph
from graphkit.errors import GraphError
from graphkit.graphfile import load_dict, load_graph


@pytest.fixture
def reg(engine_registry):
    import sweepnodes

    engine_registry.add_provider("nodes", "tests", sweepnodes)
    engine_registry.add_provider("backends", "tests", sweepnodes)
    return engine_registry


def env():
    return engine_env({"GRAPHKIT_PLUGINS": "enginenodes,sweepnodes"})


def counts(log):
    """How often each node (instance) was really computed (Count writes one line per compute)."""
    out = {}
    for line in log.read_text().splitlines() if log.exists() else []:
        node = line.split()[1]
        out[node] = out.get(node, 0) + 1
    return out


SWEEP64 = """\
graphkit: 1
name: s64
params: {{vals: {vals}}}
sweeps:
  v: {{values: "${{params.vals}}", name: "v{{index:02d}}"}}
nodes:
  c: {{type: Count, foreach: v, params: {{log: {log}, value: "${{v.value}}"}}}}
  d: {{type: Add, foreach: v, inputs: {{a: c.out}}, params: {{offset: 1}}}}
  total: {{type: Sum, inputs: {{xs: "d[*].out"}}}}
  order: {{type: Stack, inputs: {{xs: "c[*].out"}}}}
outputs: {{total: total.out, order: order.out, each: d.out}}
"""


def test_64_instance_sweep_changing_one_value_reruns_one_instance(tmp_path, write, reg):
    vals = [float(i) for i in range(64)]
    log = tmp_path / "count.log"
    g = write("s64.yaml", SWEEP64.format(vals=json.dumps(vals), log=log))
    cache = tmp_path / "cache"
    first = run_graph(g, cache=cache, registry=reg, jobs=2, out=tmp_path / "o1")
    assert len(first.computed) == 64 * 2 + 2
    np.testing.assert_array_equal(first.value("total"), np.full(8, sum(vals) + 64))  # Σ (v + 1)
    # fan-in keeps the sweep's order
    np.testing.assert_array_equal(first.value("order"), np.repeat(vals, 8))
    # one output file per instance, named by the instance
    for i in (0, 17, 63):
        np.testing.assert_array_equal(np.load(tmp_path / "o1" / "each" / f"v{i:02d}.npy"), np.full(8, vals[i] + 1))

    vals2 = list(vals)
    vals2[17] = 1000.0
    r = run_graph(g, cache=cache, registry=reg, jobs=2, overrides={"vals": vals2})
    assert sorted(r.computed) == ["c[v17]", "d[v17]", "order", "total"], r.computed
    assert len(r.cached) == 63 * 2
    np.testing.assert_array_equal(r.value("total"), np.full(8, sum(vals2) + 64))
    assert counts(log) == {**{f"c[v{i:02d}]": 1 for i in range(64)}, "c[v17]": 2}


def test_glob_batch_adding_or_changing_one_file_runs_one_instance(tmp_path, write, reg):
    import OpenImageIO as oiio

    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(3)

    def exr(name, seed_value):
        px = (rng.random((6, 5, 3)) * seed_value).astype(np.float32)
        out = oiio.ImageOutput.create(str(photos / name))
        out.open(str(photos / name), oiio.ImageSpec(5, 6, 3, "float"))
        out.write_image(px)
        out.close()
        return px.reshape(-1, 3).mean(axis=0, dtype=np.float64)

    means = {n: exr(f"{n}.exr", k + 1) for k, n in enumerate(["b", "a", "c"])}
    g = write("batch.yaml", """\
graphkit: 1
name: batch
sweeps:
  photo: {glob: "photos/*.exr"}
nodes:
  img: {type: LoadImage, foreach: photo, params: {path: "${photo.path}"}}
  mean: {type: ImageMean, foreach: photo, inputs: {image: img.image}}
  all: {type: Stack, inputs: {xs: "mean[*].out"}}
outputs: {all: all.out}
""")
    cache = tmp_path / "cache"
    r = run_graph(g, cache=cache, registry=reg)
    assert sorted(r.computed) == ["all", "img[a]", "img[b]", "img[c]", "mean[a]", "mean[b]", "mean[c]"]
    # instances in file-name order, values as written
    np.testing.assert_allclose(r.value("all"), np.concatenate([means["a"], means["b"], means["c"]]), rtol=1e-6)

    means["aa"] = exr("aa.exr", 7)  # one new file: one new instance
    r = run_graph(g, cache=cache, registry=reg)
    assert sorted(r.computed) == ["all", "img[aa]", "mean[aa]"], r.computed
    np.testing.assert_allclose(r.value("all"), np.concatenate([means[k] for k in ("a", "aa", "b", "c")]), rtol=1e-6)

    means["b"] = exr("b.exr", 9)  # one changed file: only its instance
    r = run_graph(g, cache=cache, registry=reg)
    assert sorted(r.computed) == ["all", "img[b]", "mean[b]"], r.computed


def test_matrix_range_names_and_pick(write, reg):
    g = load_graph(write("m.yaml", """\
graphkit: 1
sweeps:
  grid: {matrix: {gain: [1, 2], offset: [0.5, 1.5, 2.5]}}
  ring: {range: {start: 0, stop: 360, step: 45}, name: "az{value:03d}"}
nodes:
  k: {type: Const, foreach: grid, params: {value: "${grid.gain}", label: "o=${grid.offset}"}}
  a: {type: Add, foreach: grid, inputs: {a: k.out}, params: {offset: "${grid.offset}"}}
  r: {type: Const, foreach: ring, params: {value: "${ring.value}"}}
  one: {type: Add, inputs: {a: "r[az090].out"}}
  img: {type: LoadImage, foreach: ring, params: {path: "builtin:astronaut"}}
  sheet: {type: ContactSheet, inputs: {images: "img[*].image"}, params: {labels: "${ring[*].name}"}}
"""), reg, {})
    ks = [n for n in g.nodes if n.startswith("k[")]
    assert ks == ["k[gain=1,offset=0.5]", "k[gain=1,offset=1.5]", "k[gain=1,offset=2.5]",
                  "k[gain=2,offset=0.5]", "k[gain=2,offset=1.5]", "k[gain=2,offset=2.5]"]
    assert g.nodes["a[gain=2,offset=1.5]"].params.offset == 1.5
    assert g.nodes["a[gain=2,offset=1.5]"].inputs == {"a": ("k[gain=2,offset=1.5]", "out")}
    assert g.nodes["k[gain=1,offset=2.5]"].params.label == "o=2.5"
    assert [g.nodes[n].params.value for n in g.nodes if n.startswith("r[")] == [0, 45, 90, 135, 180, 225, 270, 315]
    assert g.nodes["one"].inputs == {"a": ("r[az090]", "out")}
    names = [f"az{a:03d}" for a in range(0, 360, 45)]
    assert g.nodes["sheet"].params.labels == names
    assert g.nodes["sheet"].inputs == {"images": [(f"img[{n}]", "image") for n in names]}


def test_a_graph_as_a_dict_goes_through_the_same_checks(tmp_path, write, reg):
    d = {"graphkit": 1, "name": "d", "sweeps": {"v": {"values": [1, 2, 3]}},
         "nodes": {"c": {"type": "Const", "foreach": "v", "params": {"value": "${v.value}"}},
                   "s": {"type": "Sum", "inputs": {"xs": "c[*].out"}}}, "outputs": {"s": "s.out"}}
    r = run_graph(d, cache=tmp_path / "c", registry=reg)
    np.testing.assert_array_equal(r.value("s"), np.full(4, 6.0))
    import yaml

    g_yaml = load_graph(write("d.yaml", yaml.safe_dump(d)), reg, {})
    assert load_dict(d, reg).digest() == g_yaml.digest()
    bad = json.loads(json.dumps(d))
    bad["nodes"]["c"]["params"] = {"valu": "${v.value}"}
    bad["nodes"]["s"]["type"] = "Summ"
    with pytest.raises(GraphError) as ei:
        load_dict(bad, reg)
    text = str(ei.value)
    assert "<dict>: nodes.c.params.valu: error: node 'c[1]' (Const): unknown param 'valu'; did you mean 'value'?" in text
    assert "<dict>: nodes.s.type: error: node 's': unknown node type 'Summ'; did you mean 'Sum'?" in text
    with pytest.raises(GraphError, match=r"nodes\.c\.params\.value: error: .*plain data.*set"):
        load_dict({**d, "nodes": {"c": {"type": "Const", "params": {"value": {1, 2}}}}}, reg)


# --------------------------------------------------------------------------------------------
# bad sweeps: located, exit 2, nothing run

BAD_BASE = """\
graphkit: 1
name: bad
sweeps:
  v: {values: [1, 2, 3]}
  photo: {glob: "photos/*.png"}
nodes:
  c: {type: Count, foreach: v, params: {value: "${v.value}", log: LOG}}
  s: {type: SaveImage, foreach: photo, inputs: {image: img.image}, params: {path: "out/${photo.name}.exr"}}
  img: {type: LoadImage, foreach: photo, params: {path: "${photo.path}"}}
outputs: {s: s.file, c: c.out}
"""


@pytest.mark.parametrize("old,new,line,col,needle", [
    ('photos/*.png', 'photos/*.jpeg', 5, 17, "glob 'photos/*.jpeg' matches no files"),
    ("values: [1, 2, 3]", "values: []", 4, 15, "'values' is an empty list"),
    ('values: [1, 2, 3]', 'values: [1, 2, 1.0]', 4, 22, "instances 0 (1) and 2 (1.0) are both named '1'"),
    ('"out/${photo.name}.exr"', '"out/same.exr"', 8, 83, "instances 'a' and 'b' both write 'out/same.exr'"),
    ('value: "${v.value}"', 'valu: "${v.value}"', 7, 41, "node 'c[1]' (Count): unknown param 'valu'; did you mean 'value'?"),
    ('value: "${v.value}"', 'value: "${v.vale}"', 7, 48, "sweep 'v' has no field 'vale'; did you mean 'value'?"),
    ("foreach: v,", "foreach: w,", 7, 29, "foreach must name a sweep, got 'w'"),
    ('inputs: {image: img.image}', 'inputs: {image: c.out}', 8, 56, "'c' has 3 instances (foreach: v) and 's' is swept over 'photo'"),
    ("outputs: {s: s.file, c: c.out}", "  t: {type: Sum, inputs: {xs: c.out}}\noutputs: {s: s.file}", 10, 31,
     "write c[*].out to take all of them, in order"),
])
def test_bad_sweeps_are_located_and_nothing_runs(tmp_path, write, reg, old, new, line, col, needle):
    (tmp_path / "photos").mkdir()
    for n in ("a", "b"):
        (tmp_path / "photos" / f"{n}.png").write_bytes(b"not read: the graph never runs")
    assert old in BAD_BASE
    text = BAD_BASE.replace(old, new).replace("LOG", str(tmp_path / "count.log"))
    g = write("bad.yaml", text)
    with pytest.raises(GraphError) as ei:
        run_graph(g, cache=tmp_path / "cache", out=tmp_path / "out", registry=reg)
    assert ei.value.exit_code == 2
    message = str(ei.value)
    assert re.search(rf"^{re.escape(str(g))}:{line}:{col}: error: .*{re.escape(needle)}", message, re.M), message
    assert not (tmp_path / "out").exists()
    assert not (tmp_path / "count.log").exists()
    assert not list((tmp_path / "cache").glob("keys/*/*.json"))


def test_bad_sweep_through_the_cli(tmp_path, write):
    g = write("bad.yaml", "graphkit: 1\nsweeps:\n  v: {values: []}\nnodes:\n"
                          "  c: {type: Const, foreach: v, params: {value: '${v.value}'}}\n")
    r = graphkit("run", g, "--cache", tmp_path / "cache", "--out", tmp_path / "out", env=env())
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.startswith(f"{g}:3:15: error: sweep 'v': 'values' is an empty list"), r.stderr
    assert not (tmp_path / "out").exists() and not list((tmp_path / "cache").glob("keys/*/*.json"))


def test_instance_names_that_collide_from_a_glob(tmp_path, write, reg):
    (tmp_path / "photos").mkdir()
    for n in ("a.png", "a.jpg", "b.png"):
        (tmp_path / "photos" / n).write_bytes(b"x")
    g = write("g.yaml", "graphkit: 1\nsweeps:\n  p: {glob: 'photos/a.*'}\nnodes:\n"
                        "  i: {type: LoadImage, foreach: p, params: {path: '${p.path}'}}\n")
    with pytest.raises(GraphError) as ei:
        load_graph(g, reg, {})
    assert (f"{g}:3:13: error: sweep 'p': instances 0 (photos/a.jpg) and 1 (photos/a.png) are both named 'a'"
            in str(ei.value)), str(ei.value)


def test_an_output_cannot_take_the_report_s_or_manifest_s_name(write, reg):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  t: {type: WriteText, params: {path: report.html}}\n"
                        "  u: {type: WriteText, params: {path: ./manifest.json}}\n")
    with pytest.raises(GraphError) as ei:
        load_graph(g, reg, {})
    assert [(d.line, d.col) for d in ei.value.diagnostics] == [(3, 39), (4, 39)], str(ei.value)
    assert "node 't' (WriteText), param 'path': 'report.html' is the name of the run's own report.html" in str(ei.value)


def test_schema_covers_sweeps():
    import enginenodes
    import jsonschema
    import sweepnodes
    import yaml

    from graphkit.registry import Registry
    from graphkit.schema import graph_schema

    reg = Registry()  # only the node types BAD_BASE uses: the point here is the sweeps section
    reg.add_provider("nodes", "io", {"LoadImage": "nodes.io.images:LoadImage", "SaveImage": "nodes.io.images:SaveImage"})
    reg.add_provider("nodes", "tests", sweepnodes)
    reg.add_provider("nodes", "tests", enginenodes)
    schema = graph_schema(reg)
    jsonschema.Draft202012Validator.check_schema(schema)
    good = yaml.safe_load(BAD_BASE)
    jsonschema.validate(good, schema)
    for bad in ({"v": {"values": []}}, {"v": {"glob": "*.png", "values": [1]}}, {"v": {"matrix": {"a": []}}},
                {"params": {"values": [1]}}, {"v": {"range": {"start": 1}}}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({**good, "sweeps": bad}, schema)
    bad = json.loads(json.dumps(good))
    bad["nodes"]["c"]["foreach"] = 3
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)


# --------------------------------------------------------------------------------------------
# fuzzing sweep graphs: a located error or a graph, never a traceback

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

FUZZ_SEED = """\
graphkit: 1
params: {vals: [1, 2, 3]}
sweeps:
  v: {values: "${params.vals}", name: "v{index}"}
  m: {matrix: {a: [1, 2], b: [x, y]}}
  r: {range: {start: 0, stop: 4, step: 1}}
nodes:
  c: {type: Const, foreach: v, params: {value: "${v.value}", label: "${m[*].name}"}}
  d: {type: Add, foreach: v, inputs: {a: c.out}}
  s: {type: Sum, inputs: {xs: ["d[*].out", "c[v1].out"]}}
  k: {type: Const, foreach: r, params: {value: "${r.value}"}}
outputs: {s: s.out, d: d.out}
"""
FUZZ_TOKENS = ["[*]", "[v1]", "[", "]", "foreach: v", "foreach: m", "${v.value}", "${v[*].name}", "${m.a}",
               "values: []", "glob: '*.nothing'", "matrix: {}", "range: {step: 0}", "name: '{nope}'",
               "name: '{index:d'", "sweeps:", "\n", "  ", ",", ":", "{", "}", "${", "*"]


@st.composite
def mutated_sweeps(draw):
    text = FUZZ_SEED
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(text)))
        if draw(st.booleans()):
            text = text[:i] + draw(st.sampled_from(FUZZ_TOKENS)) + text[i:]
        else:
            text = text[:i] + text[i + draw(st.integers(1, 12)):]
    return text


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(text=mutated_sweeps())
def test_mutated_sweep_graphs(tmp_path_factory, engine_registry, text):
    from graphkit.errors import UsageError

    p = tmp_path_factory.mktemp("fz") / "g.yaml"
    p.write_text(text)
    try:
        load_graph(p, engine_registry, {})
    except GraphError as e:
        assert e.diagnostics
        for d in e.diagnostics:
            assert d.line >= 1 and d.col >= 1 and str(d).startswith(f"{p}:{d.line}:{d.col}: error: "), d
    except UsageError:
        pass


def test_example_graphs_sweep_as_documented(engine_registry):
    from conftest import ROOT

    g = load_graph(ROOT / "graphs" / "face_ring.yaml", engine_registry, {})
    assert len(g.sweeps["light"]) >= 32
    assert len(g.instances("relit")) == len(g.sweeps["light"])
    assert g.nodes["sheet"].inputs["images"] == [(n, "image") for n in g.instances("relit")]
    assert g.nodes["preview"].inputs["frames"] == g.nodes["sheet"].inputs["images"]
    assert g.output_groups["relit"] == [f"relit/ring{i:02d}" for i in range(32)]
    assert g.nodes["save[ring07]"].params.path == "relit/ring07.exr"
    photos = sorted(p.stem for p in (ROOT / "graphs" / "photos").glob("*.png"))
    g = load_graph(ROOT / "graphs" / "makeup_batch.yaml", engine_registry, {})
    assert len(photos) >= 3 and [g.nodes[n].instance for n in g.instances("made_up")] == photos
    assert g.nodes["sheet"].params.labels == photos
