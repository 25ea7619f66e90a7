"""The engine's two backend hooks, with plain test backends (no OpenCL):

* ``Backend.declines_preference()``: an available backend that should not be chosen by a
  run's preference order here keeps the reference, with one notice per node type; a pin still
  runs it;
* ``graphkit.BackendCannotRun`` raised by a backend's compute: preferred → the node is keyed
  and computed as numpy (the same key as a numpy run: its result is a cache hit there), one
  notice; pinned → exit-2 bad input naming the node, the backend and the reason, nothing stored.
"""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import Backend, BackendCannotRun, BadInput, run_graph
from graphkit.executor import Progress

GRAPH = """\
graphkit: 1
name: hooks
nodes:
  a: {{type: Const, params: {{value: 1.0}}}}
  b: {{type: Add, inputs: {{a: a.out}}, params: {{offset: 1.0}}{pin}}}
  c: {{type: Add, inputs: {{a: b.out}}, params: {{offset: 2.0}}{pin}}}
outputs: {{c: c.out}}
"""


class AddDeclines(Backend):
    node, name, version = "Add", "slowhere", "1"

    @classmethod
    def declines_preference(cls):
        return "slower than numpy on this device"

    def compute(self, a, b=None):
        return a + (0 if b is None else b) + self.params.offset + 0.5  # visibly not numpy's


class AddTooBig(Backend):
    node, name, version = "Add", "small", "1"

    def compute(self, a, b=None):
        raise BackendCannotRun("the array needs 3 GiB; the device has 1 GiB")


class Notices(Progress):
    def __init__(self):
        self.lines = []

    def notice(self, message):
        self.lines.append(message)


@pytest.fixture
def reg(engine_registry):
    engine_registry.add_backend("Add", "slowhere", "tests", AddDeclines)
    engine_registry.add_backend("Add", "small", "tests", AddTooBig)
    return engine_registry


def _run(path, cache, reg, backends=()):
    n = Notices()
    r = run_graph(path, cache=cache, registry=reg, backends=list(backends), progress=n)
    return r, n.lines


def test_declined_preference_keeps_numpy_with_one_notice(tmp_path, write, reg):
    g = write("g.yaml", GRAPH.format(pin=""))
    r, notes = _run(g, tmp_path / "c", reg, ["slowhere"])
    assert [r.result.outcomes[n].backend for n in "bc"] == ["numpy", "numpy"]
    assert len(notes) == 1 and "not chosen by preference" in notes[0] and "slower than numpy" in notes[0]
    np.testing.assert_array_equal(r.value("c"), np.full(4, 4.0))
    pinned = write("p.yaml", GRAPH.format(pin=", backend: slowhere"))
    r, notes = _run(pinned, tmp_path / "c", reg)
    assert r.result.outcomes["c"].backend == "slowhere" and notes == []
    np.testing.assert_array_equal(r.value("c"), np.full(4, 5.0))


def test_cannot_run_preferred_falls_back_and_is_keyed_as_numpy(tmp_path, write, reg):
    g = write("g.yaml", GRAPH.format(pin=""))
    r, notes = _run(g, tmp_path / "c", reg, ["small"])
    assert [r.result.outcomes[n].backend for n in "bc"] == ["numpy", "numpy"]
    assert len(notes) == 1, notes  # one line although two nodes fell back
    assert "backend 'small' for Add cannot run node 'b' here" in notes[0] and "3 GiB" in notes[0]
    np.testing.assert_array_equal(r.value("c"), np.full(4, 4.0))
    # the fallen-back nodes carry the numpy keys: a plain numpy run finds them all cached
    r2, notes2 = _run(g, tmp_path / "c", reg)
    assert r2.computed == [] and notes2 == []
    assert {n: r2.result.outcomes[n].key for n in "abc"} == {n: r.result.outcomes[n].key for n in "abc"}


def test_cannot_run_pinned_is_bad_input(tmp_path, write, reg):
    g = write("p.yaml", GRAPH.format(pin=", backend: small"))
    with pytest.raises(BadInput) as e:
        _run(g, tmp_path / "c", reg)
    assert e.value.exit_code == 2
    msg = str(e.value)
    assert "node 'b' (Add)" in msg and "backend 'small' cannot run here" in msg and "3 GiB" in msg
