"""Small node types for the engine's own tests (loaded through GRAPHKIT_PLUGINS)."""
from __future__ import annotations

import time

import numpy as np

from graphkit import Array, Field, Image, In, Node, Scalar


class Const(Node):
    """An array filled with ``value`` (``size`` elements)."""

    outputs = {"out": Array}

    class Params(Node.Params):
        value: float = 0.0
        size: int = Field(4, ge=1)
        label: str = Field("", description="does not change the output (early-cutoff tests)")

    def compute(self):
        return np.full(self.params.size, self.params.value, np.float64)


class Add(Node):
    """a + b + offset."""

    inputs = {"a": Array, "b": In(Array, optional=True)}
    outputs = {"out": Array}

    class Params(Node.Params):
        offset: float = 0.0

    def compute(self, a, b=None):
        return a + (0 if b is None else b) + self.params.offset


class Clip(Node):
    """Clip to [lo, hi]."""

    inputs = {"x": Array}
    outputs = {"out": Array}

    class Params(Node.Params):
        lo: float = -1e300
        hi: float = 1e300

    def compute(self, x):
        return np.clip(x, self.params.lo, self.params.hi)


class Sum(Node):
    """Sum of a list of arrays (variadic port)."""

    inputs = {"xs": In(Array, variadic=True)}
    outputs = {"out": Array, "count": Scalar}

    def compute(self, xs):
        return {"out": np.sum(xs, axis=0), "count": float(len(xs))}


class Slow(Node):
    """Sleeps, then writes a big array (crash tests)."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"out": Array}

    class Params(Node.Params):
        seconds: float = 0.05
        megabytes: float = 8.0
        seed: int = 0

    def compute(self, x=None):
        time.sleep(self.params.seconds)
        n = int(self.params.megabytes * 1e6 / 8)
        rng = np.random.default_rng(self.params.seed)
        out = rng.random(n)
        if x is not None:
            out[: min(n, x.size)] += x[: min(n, x.size)]
        return out


class Fail(Node):
    """Always raises (node-failure tests)."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"out": Array}

    def compute(self, x=None):
        raise ZeroDivisionError("boom")


class WrongType(Node):
    """Returns the wrong type for its port."""

    outputs = {"out": Image}

    def compute(self):
        return np.zeros(3)


class Noop(Node):
    """Passes its input through (overhead benchmarks)."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"out": Array}

    class Params(Node.Params):
        i: int = 0

    def compute(self, x=None):
        return x if x is not None else np.zeros(1)
