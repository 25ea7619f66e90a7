"""Declared port constraints: what an input port needs, checked by the engine before compute.

A node declares them on its ports (see docs/contract.md)::

    inputs = {"photo": In(Image, "the photograph", channels=3, finite=True),
              "mask": In(Mask, "skin", same_size_as="photo"),
              "depth": In(Image, "mm", channels=1, gt=0),
              "frames": In(Image, variadic=True, min_items=1)}

Each kind of constraint is one small rule class with ``check(value, inputs)`` (None, or what is
wrong), ``describe()`` (how ``graphkit nodes`` and the schema show it) and ``spoil(value,
inputs)`` (a value that breaks the rule, made from a good one: the conformance harness feeds it
to the node and expects a refusal naming the port).  :func:`check_inputs` is the one place that
checks them; a violation is a :class:`BadInput` for the port, which the engine words as
"bad input: node 'x' (Type), port 'y': …" (exit 2).

Unconnected optional ports (absent or None) are not checked; ``same_size_as`` is not checked
when the other port is unconnected.  For a variadic port ``min_items`` applies to the list and
every other rule to each item.  A bound (ge/gt/le/lt) ignores NaN: declare ``finite=True`` to
refuse NaN and infinities.
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

from .errors import BadInput
from .types import (ARRAY, IMAGE, MASK, MESH, SCALAR, SPECTRUM, VECTOR, Camera, Image, Mask, Spectrum,
                    finite_or_message, port_type)

CAMERA = port_type(Camera)


# --------------------------------------------------------------------------------------------
# values: the array a rule looks at, and the same value with that array changed


def _array(value: Any) -> np.ndarray | None:
    """The numbers of ``value`` that finite / bounds look at (None: it has none)."""
    if isinstance(value, Image):
        return value.pixels
    if isinstance(value, Mask):
        return value.alpha
    if isinstance(value, Spectrum):
        return value.values
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
        return np.asarray(value)
    vertices = getattr(value, "vertices", None)  # a mesh
    return np.asarray(vertices) if vertices is not None else None


def _with_array(value: Any, arr: np.ndarray) -> Any:
    """``value`` with its numbers replaced by ``arr`` (the inverse of :func:`_array`)."""
    if isinstance(value, Image):
        return Image(arr, value.colorspace)
    if isinstance(value, Mask):
        return Mask(arr)
    if isinstance(value, Spectrum):
        return Spectrum(value.wavelengths, arr, value.unit)
    if isinstance(value, np.ndarray):
        return arr
    if isinstance(value, (int, float, np.number)):
        return float(arr)
    spoilt = value.copy()  # a mesh
    spoilt.vertices = arr
    return spoilt


def _where(value: Any, index: tuple[int, ...]) -> str:
    """Where the element ``index`` of ``value``'s numbers is: a Spectrum's wavelength, else the index."""
    if isinstance(value, Spectrum):
        return f"{value.wavelengths[index[0]]:g} nm"
    return f"index {index}"


def _size(value: Any) -> tuple[int, int] | None:
    """(width, height) of an Image, Mask or Camera, else None."""
    if isinstance(value, (Image, Mask, Camera)):
        return value.width, value.height
    return None


def _size_str(value: Any) -> str:
    return value.size_str() if isinstance(value, Image) else "{}×{}".format(*_size(value))


# --------------------------------------------------------------------------------------------
# the rules


@dataclass(frozen=True)
class Channels:
    """The image has one of ``allowed`` channel counts."""

    allowed: tuple[int, ...]
    types: ClassVar[tuple] = (IMAGE,)

    def check(self, value, inputs) -> str | None:
        if value.channels in self.allowed:
            return None
        return f"needs {self.describe()}, got {value.channels}"

    def describe(self) -> str:
        counts = " or ".join(str(n) for n in self.allowed)
        return f"{counts} channel{'' if self.allowed == (1,) else 's'}"

    def spoil(self, value, inputs):
        n = next(n for n in range(1, 6) if n not in self.allowed)
        px = value.pixels
        return Image(np.repeat(px[:, :, :1], n, axis=2) if n > px.shape[2] else px[:, :, :n], value.colorspace)


@dataclass(frozen=True)
class SameSizeAs:
    """Width and height equal those of input ``port`` (Images, Masks and Cameras)."""

    port: str
    types: ClassVar[tuple] = (IMAGE, MASK, CAMERA)

    def check(self, value, inputs) -> str | None:
        """The message names this port as "{port}" (filled in by :func:`port_problem`)."""
        other = inputs.get(self.port)
        if other is None or isinstance(other, list) or _size(value) == _size(other):
            return None
        kind = type(value).__name__.lower() + " " if type(value) is type(other) else ""
        return f"{kind}sizes differ: {self.port} is {_size_str(other)}, {{port}} is {_size_str(value)}"

    def describe(self) -> str:
        return f"same width and height as '{self.port}'"

    def spoil(self, value, inputs):
        if isinstance(value, Camera):
            return value.model_copy(update={"width": value.width + 1})
        arr = _array(value)
        return _with_array(value, np.concatenate([arr, arr[-1:]], axis=0))


@dataclass(frozen=True)
class Finite:
    """No NaN or infinite value."""

    types: ClassVar[tuple] = (IMAGE, MASK, SPECTRUM, SCALAR, VECTOR, ARRAY, MESH)

    def check(self, value, inputs) -> str | None:
        arr = _array(value)
        if arr.dtype.kind != "f" or arr.size == 0 or np.isfinite(_extremes(arr)).all():
            return None  # integers hold no NaN or Inf; min and max are finite only then
        return f"holds {finite_or_message(arr)}"

    def describe(self) -> str:
        return "finite (no NaN or Inf)"

    def spoil(self, value, inputs):
        arr = _array(value)
        arr = arr.astype(arr.dtype if arr.dtype.kind == "f" else np.float64)  # a copy
        arr.flat[0] = np.nan
        return _with_array(value, arr)


_OPS = {"ge": ("≥", np.greater_equal, -1), "gt": (">", np.greater, 0),
        "le": ("≤", np.less_equal, 1), "lt": ("<", np.less, 0)}


_SIDE = {"ge": "below", "gt": "at or below", "le": "above", "lt": "at or above"}


@dataclass(frozen=True)
class Bound:
    """Every value ``op`` ``limit`` (op: ge, gt, le, lt); NaN is left to :class:`Finite`.
    ``interval`` ("[0, 1]") is the port's whole range when it declares a bound on each side:
    the message then names it."""

    op: str
    limit: float
    interval: str = ""
    types: ClassVar[tuple] = (IMAGE, MASK, SPECTRUM, SCALAR, VECTOR, ARRAY)

    def check(self, value, inputs) -> str | None:
        sym, ok, _ = _OPS[self.op]
        arr = _array(value)
        low = self.op in ("ge", "gt")
        # one pass when nothing is wrong: the extreme on the bound's side keeps it (a NaN makes
        # the extreme NaN, which does not: the full check below then leaves the NaN out)
        if arr.size == 0 or ok(_extremes(arr)[0 if low else 1], self.limit):
            return None
        bad = ~ok(arr, self.limit) & ~np.isnan(arr) if arr.dtype.kind == "f" else ~ok(arr, self.limit)
        if not bad.any():
            return None
        rule = f"lie in {self.interval}" if self.interval else f"be {sym} {self.limit:g}"
        if arr.ndim == 0:
            return f"must {rule}, got {float(arr):g}"
        worst = np.min(arr[bad]) if low else np.max(arr[bad])
        n = int(bad.sum())
        side = "negative" if (self.op, self.limit) == ("ge", 0) else f"{_SIDE[self.op]} {self.limit:g}"
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        return (f"values must {rule}; {n} of {arr.size} {'is' if n == 1 else 'are'} {side} "
                f"({'min' if low else 'max'} {float(worst):.6g}), the first at {_where(value, first)}")

    def describe(self) -> str:
        return f"values {_OPS[self.op][0]} {self.limit:g}"

    def spoil(self, value, inputs):
        """A value at a strict bound, or half a unit beyond an inclusive one."""
        _, _, side = _OPS[self.op]
        bad = self.limit + side * 0.5 * (abs(self.limit) or 1.0)
        arr = np.array(_array(value))
        arr.flat[0] = bad
        return _with_array(value, arr)


@dataclass(frozen=True)
class MinItems:
    """A variadic port gets at least ``count`` connections."""

    count: int
    types: ClassVar[tuple] = ()  # any type; the port must be variadic

    def check(self, value, inputs) -> str | None:
        if len(value) >= self.count:
            return None
        return f"needs at least {self.count} connection{'s' if self.count != 1 else ''}, got {len(value)}"

    def describe(self) -> str:
        return f"at least {self.count} connection{'s' if self.count != 1 else ''}"

    def spoil(self, value, inputs):
        return list(value)[: self.count - 1]


Rule = Channels | SameSizeAs | Finite | Bound | MinItems


@dataclass(frozen=True)
class Constraints:
    """What one input port declares it needs (every field optional; see the module doc)."""

    channels: tuple[int, ...] = ()
    same_size_as: str | None = None
    finite: bool = False
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    min_items: int | None = None

    @classmethod
    def make(cls, channels: int | tuple[int, ...] | None = None, **kw) -> "Constraints":
        if isinstance(channels, int):
            channels = (channels,)
        return cls(channels=tuple(channels or ()), **kw)

    def rules(self) -> tuple[Rule, ...]:
        """The rules in the order they are checked."""
        return _rules(self)

    def _make_rules(self) -> tuple[Rule, ...]:
        out: list = []
        if self.min_items is not None:
            out.append(MinItems(self.min_items))
        if self.channels:
            out.append(Channels(self.channels))
        if self.same_size_as:
            out.append(SameSizeAs(self.same_size_as))
        if self.finite:
            out.append(Finite())
        bounds = {op: float(getattr(self, op)) for op in _OPS if getattr(self, op) is not None}
        interval = self._interval(bounds)
        out += [Bound(op, limit, interval) for op, limit in bounds.items()]
        return tuple(out)

    @staticmethod
    def _interval(bounds: dict) -> str:
        """"[0, 1]" for ge=0, le=1 ("(" / ")" for gt / lt); "" unless bounded on both sides."""
        lo = [(op, v) for op, v in bounds.items() if op in ("ge", "gt")]
        hi = [(op, v) for op, v in bounds.items() if op in ("le", "lt")]
        if not (lo and hi):
            return ""
        (lop, lv), (hop, hv) = lo[-1], hi[0]
        return f"{'[' if lop == 'ge' else '('}{lv:g}, {hv:g}{']' if hop == 'le' else ')'}"

    def __bool__(self) -> bool:
        return self != Constraints()

    def describe(self) -> list[str]:
        return [r.describe() for r in self.rules()]

    @classmethod
    def from_json(cls, data: dict) -> "Constraints":
        """The inverse of :meth:`to_json`."""
        return cls.make(**data)

    def to_json(self) -> dict:
        """The declared fields (those not at their default), as JSON."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v != f.default:
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


@functools.lru_cache(maxsize=None)
def _rules(c: Constraints) -> tuple[Rule, ...]:
    return c._make_rules()


# --------------------------------------------------------------------------------------------
# checking


def _problem(rule, port: str, value, inputs: dict) -> str | None:
    msg = rule.check(value, inputs)
    return msg.replace("{port}", port) if msg else None


def _extremes(arr: np.ndarray) -> tuple:
    """(min, max) of a non-empty ``arr`` (a NaN makes both NaN: numpy propagates it).  Within one
    :func:`port_problem` call they are computed once for all its rules (finite, ge, le: two passes
    over a frame instead of four); the memo is dropped when that call returns, so a value
    changed in place between checks is read again."""
    memo = getattr(_MEMO, "extremes", None)
    got = None if memo is None else memo.get(id(arr))
    if got is None or got[0] is not arr:
        got = (arr, arr.min(), arr.max())
        if memo is not None:
            memo[id(arr)] = got
    return got[1], got[2]


_MEMO = threading.local()  # _extremes' memo during one port_problem call (per thread)


def port_problem(port, value: Any, inputs: dict) -> str | None:
    """What is wrong with ``value`` on ``port`` (a :class:`graphkit.node.Port`), or None."""
    _MEMO.extremes = {}
    try:
        return _port_problem(port, value, inputs)
    finally:
        _MEMO.extremes = None


def _port_problem(port, value: Any, inputs: dict) -> str | None:
    for rule in port.constraints.rules():
        if isinstance(rule, MinItems) or not port.variadic:
            msg = _problem(rule, port.name, value, inputs)
            if msg:
                return msg
            continue
        for i, item in enumerate(value):
            msg = _problem(rule, port.name, item, inputs)
            if msg:
                return f"item {i}: {msg}"
    return None


def check_inputs(node_cls, inputs: dict) -> None:
    """Raise :class:`BadInput` for the first input of ``node_cls`` that breaks a constraint."""
    for name in node_cls.constrained_ports:
        value = inputs.get(name)
        if value is not None:
            msg = port_problem(node_cls.in_ports[name], value, inputs)
            if msg:
                raise BadInput(name, msg)


def compute_checked(node, **inputs):
    """``node.compute(**inputs)`` after ``node``'s declared constraints, as the engine calls it
    (for the studio, the conformance harness and tests that call a node directly)."""
    check_inputs(type(node), inputs)
    return node.compute(**inputs)


def declaration_problem(port, ports: dict) -> str | None:
    """Why ``port``'s constraints cannot apply to its type (checked when the class is made)."""
    for rule in port.constraints.rules():
        if isinstance(rule, MinItems) and not port.variadic:
            return "min_items is for variadic ports"
        if rule.types and not _type_in(port.type, rule.types):
            return f"{rule.describe()!r} does not apply to a {port.type.name} port"
        if isinstance(rule, SameSizeAs):
            other = ports.get(rule.port)
            if other is None or other is port:
                return f"same_size_as names '{rule.port}', which is not another input port"
            if not _type_in(other.type, rule.types):
                return f"same_size_as names '{rule.port}', a {other.type.name} port (it has no size)"
    return None


def _type_in(ptype, types: tuple) -> bool:
    return ptype in types


__all__ = ["Constraints", "Channels", "SameSizeAs", "Finite", "Bound", "MinItems", "check_inputs",
           "compute_checked", "port_problem", "declaration_problem"]
