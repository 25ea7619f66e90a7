"""Graph files: every problem is reported as file:line:col with the node and port, exit 2."""
import re

import pytest

from conftest import graphkit
from graphkit.errors import GraphError, UsageError
from graphkit.graphfile import load_graph

GOOD = """\
graphkit: 1
name: g
params: {eps: 0.001}
nodes:
  photo: {type: LoadImage, params: {path: "builtin:astronaut"}}
  ratio:
    type: RatioImage
    inputs: {a: photo.image, b: photo.image}
    params: {eps: "${params.eps}"}
outputs: {r: ratio.ratio}
"""


def errors(write, engine_registry, text, **over):
    p = write("g.yaml", text)
    with pytest.raises(GraphError) as ei:
        load_graph(p, engine_registry, over)
    return [(d.line, d.col, d.message) for d in ei.value.diagnostics]


def test_good_graph_loads(write, engine_registry):
    g = load_graph(write("g.yaml", GOOD), engine_registry, {"eps": 0.5})
    assert g.nodes["ratio"].params.eps == 0.5
    assert g.outputs == {"r": ("ratio", "ratio")}


@pytest.mark.parametrize("old,new,line,col,expect", [
    ("type: RatioImage", "type: RatioImag", 7, 11, "unknown node type 'RatioImag'; did you mean 'RatioImage'?"),
    ("{a: photo.image, b: photo.image}", "{a: photo.image, c: photo.image}", 8, 30,
     "node 'ratio' (RatioImage) has no input port 'c'"),
    ("{a: photo.image, b: photo.image}", "{a: photo.image, b: photo.imag}", 8, 33,
     "node 'photo' (LoadImage) has no output port 'imag'; did you mean 'image'?"),
    ("{a: photo.image, b: photo.image}", "{a: photo.image}", 8, 13, "missing required input 'b' (Image)"),
    ('{eps: "${params.eps}"}', "{eps: -1}", 9, 19, "param 'eps': Input should be greater than 0 (got -1)"),
    ('{eps: "${params.eps}"}', "{epsilon: 1}", 9, 14, "unknown param 'epsilon'"),
    ('{eps: "${params.eps}"}', '{eps: "${params.ep}"}', 9, 19, "unknown graph param 'ep'; did you mean 'eps'?"),
    ("name: g", "name: g\nnodez: {}", 3, 1, "unknown top-level key 'nodez'; did you mean 'nodes'?"),
    ("outputs: {r: ratio.ratio}", "outputs: {r: ratios.ratio}", 10, 14, "no node named 'ratios'; did you mean 'ratio'?"),
    ("graphkit: 1", "graphkit: 2", 1, 11, "unsupported graph format 2"),
    ("    type: RatioImage", "    type: RatioImage\n    colour: red", 8, 5, "unknown key 'colour'"),
    ('path: "builtin:astronaut"', 'path: "missing.png"', 5, 43, "file not found"),
    ('path: "builtin:astronaut"', 'path: "builtin:moon"', 5, 43, "unknown builtin image 'builtin:moon'"),
])
def test_error_located(write, engine_registry, old, new, line, col, expect):
    assert old in GOOD
    errs = errors(write, engine_registry, GOOD.replace(old, new))
    assert any(expect in m for _, _, m in errs), errs
    assert (line, col) in [(l, c) for l, c, m in errs if expect in m], errs


def test_wrong_port_type(write, engine_registry):
    text = GOOD.replace("outputs: {r: ratio.ratio}", "  k: {type: Const}\n  bad: {type: RatioImage, inputs: {a: k.out, b: photo.image}}\noutputs: {r: ratio.ratio}")
    errs = errors(write, engine_registry, text)
    assert any("input 'a' takes Image but k.out gives Array" in m for _, _, m in errs), errs


def test_cycle(write, engine_registry):
    text = "graphkit: 1\nnodes:\n  x: {type: Add, inputs: {a: y.out}}\n  y: {type: Add, inputs: {a: x.out}}\n"
    errs = errors(write, engine_registry, text)
    assert any(m.startswith("cycle: ") and "x" in m and "y" in m for _, _, m in errs), errs


def test_duplicate_node_names(write, engine_registry):
    text = "graphkit: 1\nnodes:\n  x: {type: Const}\n  x: {type: Const}\n"
    assert (4, 3, "duplicate key 'x'") in errors(write, engine_registry, text)


def test_python_tags_cannot_run_code(write, engine_registry, tmp_path):
    marker = tmp_path / "pwned"
    text = GOOD.replace('path: "builtin:astronaut"',
                        f'path: !!python/object/apply:os.system ["touch {marker}"]')
    errs = errors(write, engine_registry, text)
    assert any("YAML tag '!!python/object/apply:os.system' is not allowed" in m for _, _, m in errs)
    assert not marker.exists()


def test_malformed_yaml_and_non_mapping(write, engine_registry):
    assert errors(write, engine_registry, "graphkit: 1\nnodes: {a: [}\n")[0][:2] == (2, 13)
    assert "must be a mapping" in errors(write, engine_registry, "- 1\n- 2\n")[0][2]
    assert "empty" in errors(write, engine_registry, "")[0][2]


def test_set_unknown_param(write, engine_registry):
    with pytest.raises(UsageError, match="no param 'epz'; did you mean 'eps'"):
        load_graph(write("g.yaml", GOOD), engine_registry, {"epz": 1})


def test_cli_exit_codes_and_no_traceback(write, tmp_path):
    bad = write("bad.yaml", GOOD.replace("RatioImage", "RatioImag"))
    r = graphkit("validate", bad)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert re.match(rf"^{re.escape(str(bad))}:7:11: error: node 'ratio': unknown node type", r.stderr), r.stderr
    r = graphkit("run", tmp_path / "nope.yaml")
    assert r.returncode == 2 and "graph file not found" in r.stderr and "Traceback" not in r.stderr
    r = graphkit("validate", write("ok.yaml", GOOD), "--set", "eps=0.1")
    assert r.returncode == 0, r.stderr


def test_output_path_cannot_escape(write, engine_registry):
    text = GOOD.replace("outputs: {r: ratio.ratio}",
                        "  s: {type: SaveImage, inputs: {image: ratio.ratio}, params: {path: ../../evil.png}}\noutputs: {r: s.file}")
    errs = errors(write, engine_registry, text)
    assert any("relative path inside the output folder" in m for _, _, m in errs), errs


def test_two_outputs_writing_one_file_are_refused_before_running(write, engine_registry):
    text = GOOD.replace("outputs: {r: ratio.ratio}",
                        "  s1: {type: SaveImage, inputs: {image: ratio.ratio}, params: {path: x/r.exr}}\n"
                        "  s2: {type: SaveImage, inputs: {image: photo.image}, params: {path: x//r.exr}}\n"
                        "outputs: {a: s1.file, b: s2.file}")
    errs = errors(write, engine_registry, text)
    assert errs == [(11, 70, "nodes 's1' and 's2' both write 'x/r.exr' into --out")], errs


ANCHORS = [  # (text, data or None, the one error or diagnostics): as PyYAML's composer read them
    ("a: &x {k: 1}\nb: *x\nc: [*x, *x]\n", {"a": {"k": 1}, "b": {"k": 1}, "c": [{"k": 1}, {"k": 1}]}, []),
    ("&k k: 1\n*k : 2\n", {"k": 1}, ["f:1:1: error: duplicate key 'k'"]),
    ("a: !foo [1, &z 2]\nb: *z\n", {"a": None, "b": 2},
     ["f:1:4: error: YAML tag '!foo' is not allowed: graph files hold plain data only"]),
    ("? [a]\n: 1\nb: 2\n", {"b": 2}, ["f:1:3: error: mapping keys must be plain scalars"]),
    ("a: *x\n", None, ["f:1:4: error: malformed YAML: found undefined alias"]),
    ("a: &x 1\nb: &x 2\n", None, ["f:2:4: error: malformed YAML: found duplicate anchor; first occurrence second occurrence"]),
    ("a: 1\n---\nb: 2\n", None, ["f:2:1: error: malformed YAML: expected a single document in the stream but found another document"]),
    ("a: &x [1, *x]\n", None, ["f:1:1: error: malformed YAML: nested too deeply"]),
    ("a: &x [1, *x]\nb: *y\n", None, ["f:2:4: error: malformed YAML: found undefined alias"]),
    ("a: *y\nb: [\n", None, ["f:3:1: error: malformed YAML: while parsing a flow node did not find expected node content"]),
    ("a: *y\nb: " + "[" * 101 + "]" * 101 + "\n", None, ["f:2:103: error: YAML nested too deeply: more than 100 levels of lists and mappings"]),
]


@pytest.mark.parametrize("text, data, errors", ANCHORS)
def test_anchors_aliases_and_their_errors(text, data, errors):
    """Issue 25: graph files are composed from the parser's events in one pass; anchors,
    aliases and the order in which errors are found are as PyYAML's composer had them (a
    syntax error or too deep a nesting anywhere comes before an alias error, an alias error
    before a cycle)."""
    from graphkit.graphfile import parse_yaml

    if data is None:
        with pytest.raises(GraphError) as e:
            parse_yaml(text, "f")
        assert [str(d) for d in e.value.diagnostics] == errors
    else:
        doc = parse_yaml(text, "f")
        assert doc.data == data and [str(d) for d in doc.diags] == errors
