"""Declared port constraints: the engine refuses every violation before compute (exit 2, one
message naming node, type and port), whichever backend runs; declarations that cannot apply
fail when the class is defined."""
import textwrap

import numpy as np
import pytest

from conftest import engine_env, graphkit

PLUGIN = '''
import numpy as np
from graphkit import Field, Image, In, Mask, Node, Scalar


class Pixels(Node):
    """A constant image (with one NaN when nan is true)."""
    outputs = {"out": Image}

    class Params(Node.Params):
        w: int = 4
        h: int = 3
        c: int = 3
        value: float = 0.5
        nan: bool = False

    def compute(self):
        p = self.params
        px = np.full((p.h, p.w, p.c), p.value, np.float32)
        if p.nan:
            px[1, 1, 0] = np.nan
        return Image(px)


class Num(Node):
    outputs = {"out": Scalar}

    class Params(Node.Params):
        x: float = 1.0

    def compute(self):
        return self.params.x


class ToMask(Node):
    inputs = {"image": Image}
    outputs = {"out": Mask}

    def compute(self, image):
        return Mask(image.pixels[:, :, 0])


class Needs(Node):
    """Declares one constraint of each kind."""
    inputs = {"img": In(Image, "rgb", channels=3, finite=True, ge=0, le=1),
              "mask": In(Mask, "weights", optional=True, same_size_as="img"),
              "gain": In(float, "gain", optional=True, gt=0),
              "extra": In(Image, "more", variadic=True, optional=True, min_items=1, channels=(1, 3))}
    outputs = {"out": Image}

    def compute(self, img, mask=None, gain=1.0, extra=()):
        return Image(img.pixels * gain)

    @classmethod
    def examples(cls):
        img = Image(np.full((3, 4, 3), 0.5, np.float32))
        return [({}, {"img": img, "mask": Mask(np.ones((3, 4), np.float32)), "gain": 2.0,
                      "extra": [Image(np.zeros((3, 4, 1), np.float32))]})]


class Sized(Node):
    """same_size_as an optional port, which only the second example connects."""
    inputs = {"img": In(Image, "image", same_size_as="mask"), "mask": In(Mask, "weights", optional=True)}
    outputs = {"out": Image}

    def compute(self, img, mask=None):
        return img

    @classmethod
    def examples(cls):
        img = Image(np.zeros((3, 4, 1), np.float32))
        return [({}, {"img": img}), ({}, {"img": img, "mask": Mask(np.ones((3, 4), np.float32))})]
'''

GOOD = {"img": "p.out", "mask": "m.out", "gain": "g.out", "extra": ["p1.out"]}


def graph(inputs=None, **over) -> str:
    params = {"p": {}, "pm": {}, "p1": {"c": 1}, "g": {}}
    for k, v in over.items():
        params[k].update(v)
    inputs = inputs or GOOD
    fmt = lambda d: "{" + ", ".join(f"{k}: {v}" for k, v in d.items()) + "}"  # noqa: E731
    return textwrap.dedent(f"""\
        graphkit: 1
        nodes:
          p: {{type: Pixels, params: {fmt(params['p'])}}}
          pm: {{type: Pixels, params: {fmt(params['pm'])}}}
          m: {{type: ToMask, inputs: {{image: pm.out}}}}
          p1: {{type: Pixels, params: {fmt(params['p1'])}}}
          g: {{type: Num, params: {fmt(params['g'])}}}
          n: {{type: Needs, inputs: {fmt(inputs)}}}
        outputs: {{o: n.out}}
        """)


@pytest.fixture
def env(tmp_path):
    (tmp_path / "contractnodes.py").write_text(PLUGIN)
    e = engine_env()
    e["PYTHONPATH"] = f"{tmp_path}:{e['PYTHONPATH']}"
    e["GRAPHKIT_PLUGINS"] = "contractnodes"
    return e


def run(tmp_path, env, text):
    g = tmp_path / "g.yaml"
    g.write_text(text)
    return graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o", env=env)


def test_good_inputs_run(tmp_path, env):
    r = run(tmp_path, env, graph())
    assert r.returncode == 0, r.stderr


CASES = [
    ("channels", {"p": {"c": 1}}, "port 'img': needs 3 channels, got 1"),
    ("finite", {"p": {"nan": "true"}}, "port 'img': holds 1 NaN and 0 Inf values (first at index (1, 1, 0))"),
    ("ge", {"p": {"value": -0.25}}, "port 'img': values must lie in [0, 1]; 36 of 36 are negative (min -0.25), the first at index (0, 0, 0)"),
    ("le", {"p": {"value": 1.5}}, "port 'img': values must lie in [0, 1]; 36 of 36 are above 1 (max 1.5), the first at index (0, 0, 0)"),
    ("same_size_as", {"pm": {"w": 5}}, "port 'mask': sizes differ: img is 4×3×3, mask is 5×3"),
    ("gt", {"g": {"x": 0.0}}, "port 'gain': must be > 0, got 0"),
    ("variadic item", {"p1": {"c": 2}}, "port 'extra': item 0: needs 1 or 3 channels, got 2"),
]


@pytest.mark.parametrize("what,over,needle", CASES, ids=[c[0] for c in CASES])
def test_each_violation_is_refused_naming_the_port(tmp_path, env, what, over, needle):
    r = run(tmp_path, env, graph(**over))
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    assert f"bad input: node 'n' (Needs), {needle}" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_min_items_on_an_empty_variadic_list(tmp_path, env):
    r = run(tmp_path, env, graph(inputs={**GOOD, "extra": "[]"}))
    assert r.returncode == 2, r.stderr
    assert "bad input: node 'n' (Needs), port 'extra': needs at least 1 connection, got 0" in r.stderr


def test_unconnected_optional_ports_are_not_checked(tmp_path, env):
    r = run(tmp_path, env, graph(inputs={"img": "p.out"}))
    assert r.returncode == 0, r.stderr


def test_the_checker_refuses_what_each_rule_spoils():
    """Every rule's spoil() gives a value its own check() refuses (what the harness relies on)."""
    from graphkit.contract import check_inputs
    from graphkit.errors import BadInput
    from graphkit.types import Image, Mask

    ns: dict = {}
    exec(PLUGIN, ns)
    Needs = ns["Needs"]
    _, good = Needs.examples()[0]
    check_inputs(Needs, good)
    for name in Needs.constrained_ports:
        port = Needs.in_ports[name]
        for rule in port.constraints.rules():
            v = good[name]
            bad = rule.spoil(v, good) if (not port.variadic or rule.__class__.__name__ == "MinItems") \
                else [rule.spoil(v[0], good)]
            with pytest.raises(BadInput) as e:
                check_inputs(Needs, {**good, name: bad})
            assert e.value.port == name, (rule, e.value)
    assert isinstance(good["img"], Image) and isinstance(good["mask"], Mask)


@pytest.mark.parametrize("decl,problem", [
    ('In(Mask, channels=3)', "'3 channels' does not apply to a Mask port"),
    ('In(Image, same_size_as="nope")', "same_size_as names 'nope', which is not another input port"),
    ('In(Image, same_size_as="x")', "same_size_as names 'x', which is not another input port"),
    ('In(Image, min_items=1)', "min_items is for variadic ports"),
    ('In(Json, ge=0)', "'values ≥ 0' does not apply to a Json port"),
])
def test_declarations_that_cannot_apply_fail_at_class_definition(decl, problem):
    from graphkit import Image, In, Json, Mask, Node  # noqa: F401 - used by the declarations

    with pytest.raises(TypeError) as e:
        type("Bad", (Node,), {"inputs": {"x": eval(decl)}, "outputs": {"o": Image},
                              "compute": lambda self, **kw: None})
    assert f"Bad: input 'x': {problem}" in str(e.value)


def test_bounds_ignore_nan_unless_finite_is_declared():
    from graphkit.contract import Bound, Finite

    a = np.array([np.nan, 0.5])
    assert Bound("ge", 0.0).check(a, {}) is None
    assert Finite().check(a, {}) is not None
    # a NaN does not hide a value past the bound (nor one at a strict bound, on either side)
    assert "1 of 3 is negative (min -1)" in Bound("ge", 0.0).check(np.array([np.nan, -1.0, 0.5]), {})
    assert "1 of 3 is above 1 (max 2)" in Bound("le", 1.0).check(np.array([0.5, np.nan, 2.0], np.float32), {})
    assert Bound("gt", 0.0).check(np.zeros((2, 2, 1), np.float32), {}) is not None
    assert Bound("lt", 1.0).check(np.ones(3, np.int64), {}) is not None
    assert Bound("ge", 0.0).check(np.zeros((0, 3)), {}) is None


def test_conform_breaks_every_declared_constraint(tmp_path, env):
    r = graphkit("conform", "contractnodes", env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("ok    Needs/contract")]
    for needle in ["port 'img': 3 channels: refused", "port 'img': finite (no NaN or Inf): refused",
                   "port 'img': values ≥ 0: refused", "port 'img': values ≤ 1: refused",
                   "port 'mask': same width and height as 'img': refused", "port 'gain': values > 0: refused",
                   "port 'extra': at least 1 connection: refused", "port 'extra': 1 or 3 channels: refused"]:
        assert any(ln.endswith(needle) for ln in lines), (needle, r.stdout)
    # same_size_as is broken in an example that connects the port it names (it applies only there)
    assert "ok    Sized/contract example 1: port 'img': same width and height as 'mask': refused" in r.stdout


def test_conform_fails_when_a_constraint_is_not_enforced(tmp_path, env, monkeypatch):
    import sys

    from graphkit import contract, conformance
    from graphkit.registry import discover

    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GRAPHKIT_PLUGINS", "contractnodes")
    monkeypatch.delitem(sys.modules, "contractnodes", raising=False)
    reg = discover()
    assert all(f.ok for f in conformance.check_contracts(reg, plugin="contractnodes"))
    monkeypatch.setattr(contract, "check_inputs", lambda cls, inputs: None)  # the engine forgets to check
    found = conformance.check_contracts(reg, plugin="contractnodes")
    assert found and not any(f.ok for f in found), [str(f) for f in found]
    assert "accepted a value that breaks it" in found[0].message


def test_finite_and_bounds_read_a_value_changed_in_place_again():
    """finite / ge / le share one min and max per check of a port (graphkit.contract._extremes):
    an array checked, then changed in place, is checked afresh; ±Inf and NaN anywhere refused."""
    from graphkit import Image, In, Node
    from graphkit.contract import check_inputs
    from graphkit.errors import BadInput

    Node_ = type("Bounded", (Node,), {"inputs": {"x": In(Image, finite=True, ge=0, le=1)},
                                      "outputs": {"o": Image}, "compute": lambda self, x: {"o": x}})
    img = Image(np.full((4, 5, 3), 0.5, np.float32))
    check_inputs(Node_, {"x": img})
    for bad, needle in ((np.nan, "1 NaN and 0 Inf"), (np.inf, "0 NaN and 1 Inf"), (-np.inf, "0 NaN and 1 Inf"),
                        (2.0, "above 1"), (-1.0, "negative")):
        img.pixels[2, 3, 1] = bad
        with pytest.raises(BadInput) as e:
            check_inputs(Node_, {"x": img})
        assert needle in str(e.value), (bad, e.value)
        img.pixels[2, 3, 1] = 0.5
        check_inputs(Node_, {"x": img})
