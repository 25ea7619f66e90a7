"""Fuzzing graph files: whatever the bytes, loading gives a located error or a graph, never a
traceback."""
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from graphkit.errors import GraphError, UsageError
from graphkit.graphfile import load_graph

SEED = """\
graphkit: 1
name: fuzz
params: {v: 1.5, n: 3}
nodes:
  a: {type: Const, params: {value: "${params.v}", size: 3}}
  b:
    type: Add
    inputs: {a: a.out, b: a.out}
    params: {offset: 2}
  s: {type: Sum, inputs: {xs: [a.out, b.out]}}
  photo: {type: LoadImage, params: {path: "builtin:astronaut"}}
outputs: [s.out, b.out]
"""
TOKENS = ["{", "}", "[", "]", ":", ",", "-", "\n", "  ", "'", '"', "&a", "*a", "!!python/name:os.system",
          "!!binary", "${params.v}", "${params.", "a.out", "nodes:", "type:", "inputs:", "~", "null",
          ".nan", "1e999", "<<:", "? ", "|", ">", "#", "\t", "\x00", "é", "graphkit: 1"]


def check(tmp_path, text: str):
    p = tmp_path / "fuzz.yaml"
    p.write_bytes(text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text)
    try:
        load_graph(p, check.registry, {})
    except GraphError as e:
        assert e.diagnostics
        for d in e.diagnostics:
            assert d.file == str(p) and d.line >= 1 and d.col >= 1, d
            assert str(d).startswith(f"{p}:{d.line}:{d.col}: error: ")
    except UsageError:
        pass


@st.composite
def mutated(draw):
    text = SEED
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(text)))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        if op == "insert":
            text = text[:i] + draw(st.sampled_from(TOKENS) | st.text(max_size=6)) + text[i:]
        elif op == "delete":
            text = text[:i] + text[i + draw(st.integers(1, 20)):]
        else:
            j = i + draw(st.integers(1, 8))
            text = text[:i] + draw(st.sampled_from(TOKENS)) + text[j:]
    return text


@settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))
@given(text=mutated())
def test_mutated_graphs(tmp_path_factory, engine_registry, text):
    check.registry = engine_registry
    check(tmp_path_factory.mktemp("f"), text)


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(raw=st.binary(max_size=200) | st.lists(st.sampled_from(TOKENS), max_size=30).map(lambda t: "".join(t).encode()))
def test_random_bytes(tmp_path_factory, engine_registry, raw):
    check.registry = engine_registry
    check(tmp_path_factory.mktemp("f"), raw)


def test_alias_bomb_is_refused(tmp_path, engine_registry):
    lines = ["graphkit: 1", "a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i-1}"] * 9) + "]")
    check.registry = engine_registry
    p = tmp_path / "bomb.yaml"
    p.write_text("\n".join(lines) + "\n")
    try:
        load_graph(p, engine_registry, {})
    except GraphError as e:
        assert "too large" in str(e)
    else:
        raise AssertionError("alias bomb accepted")
