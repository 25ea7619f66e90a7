"""Backend conformance harness (public: ``graphkit conform [PLUGIN]``, or call it from tests).

Every registered backend of a node type must agree with the node's own (numpy reference)
compute on the node's ``examples()``, within a tolerance.  For plugin authors:

* ``examples()`` on the node class returns a list of ``(params dict, inputs dict)`` cases; give
  it small inputs that exercise the edges of the maths (zeros, large values, odd sizes);
* ``tolerance`` on the node class is a dict, optionally refined by the same attribute on the
  backend class (the backend's keys win)::

      tolerance = {"rtol": 1e-5,          # relative tolerance per value (default 1e-5)
                   "atol": 1e-6,          # absolute tolerance per value (default 1e-6)
                   "bad_fraction": 0.0}   # share of values allowed outside rtol/atol (default 0)

  a float value passes when ``|got - ref| <= atol + rtol * |ref|`` (``numpy.isclose``; NaN
  equals NaN); integer and boolean arrays must be equal; ``bad_fraction`` is for outputs where a
  few values legitimately differ (rasterisers disagree on silhouette pixels);
* every output port of every case is compared, array by array, after the port type splits the
  value into arrays (as the cache does).

From a plugin's own test suite::

    from graphkit.conformance import check_backends
    from graphkit.registry import default_registry

    def test_my_backends_conform():
        findings = check_backends(default_registry(), plugin="my-plugin")
        assert findings and all(f.ok for f in findings), [str(f) for f in findings if not f.ok]

``graphkit conform my-plugin`` prints one line per backend and example and exits 0 when all
agree, 1 when one disagrees or raises, 2 when a backend cannot be checked here (not available,
or its node has no examples) unless ``--allow-unavailable``.

It also checks the node types' declared port constraints (:mod:`graphkit.contract`): for each
one it makes a value that breaks it (from the node's first example that connects the port, or
from a small value the port's constraints allow) and expects the refusal the engine gives, a
:class:`BadInput` (exit 2) naming the port; ``check_contracts`` does this from a test suite.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .node import Context, probe
from .registry import NUMPY, Registry
from .store import value_parts


DEFAULT_TOLERANCE = {"rtol": 1e-5, "atol": 1e-6, "bad_fraction": 0.0}


@dataclass
class Finding:
    node: str
    backend: str
    case: int  # the example's index, -1 when no example was run
    ok: bool
    message: str
    checked: bool = True  # False when the backend could not be run here

    def __str__(self) -> str:
        return f"{self.node}/{self.backend} example {self.case}: {self.message}"


def _compare(ptype, ref, got, rtol, atol, bad_fraction=0.0) -> str | None:
    _, ra, _ = value_parts(ptype, ref)
    _, ga, _ = value_parts(ptype, got)
    if len(ra) != len(ga):
        return f"{len(ga)} arrays instead of {len(ra)}"
    for i, (x, y) in enumerate(zip(ra, ga)):
        if x.shape != y.shape:
            return f"array {i}: shape {y.shape} instead of {x.shape}"
        if x.dtype.kind == "f" or y.dtype.kind == "f":
            close = np.isclose(y, x, rtol=rtol, atol=atol, equal_nan=True)
            frac = 1.0 - close.mean() if close.size else 0.0
            if frac > bad_fraction:
                err = np.max(np.abs(y.astype(np.float64) - x.astype(np.float64)))
                return (f"array {i}: max abs difference {err:.3g}, {frac:.2%} of values outside "
                        f"rtol={rtol}, atol={atol} (allowed {bad_fraction:.2%})")
        elif not np.array_equal(x, y):
            return f"array {i}: values differ"
    return None


def _normalise(cls, result):
    outs = cls.out_ports
    if len(outs) == 1 and not (isinstance(result, dict) and set(result) == set(outs)):
        return {next(iter(outs)): result}
    return result


def check_node(reg: Registry, node: str, backends: list[str] | None = None) -> list[Finding]:
    """Run every available non-reference backend of ``node`` (or those in ``backends``) against
    the reference on the node's examples."""
    cls = reg.node_class(node)
    findings = []
    cases = cls.examples()
    for bname in reg.backend_names(node):
        if bname == NUMPY or (backends is not None and bname not in backends):
            continue
        bcls, why = _checkable(reg, node, bname, bool(cases))
        if why:
            findings.append(Finding(node, bname, -1, False, why, checked=False))
            continue
        tol = {**DEFAULT_TOLERANCE, **cls.tolerance, **getattr(bcls, "tolerance", {})}
        findings += [Finding(node, bname, i, *_check_case(cls, bcls, params, inputs, tol))
                     for i, (params, inputs) in enumerate(cases)]
    return findings


def _checkable(reg: Registry, node: str, bname: str, has_cases: bool) -> tuple[type | None, str | None]:
    """(the backend class, None), or (None, why it cannot be checked here)."""
    try:
        bcls = reg.backend_class(node, bname)
    except Exception as e:  # noqa: BLE001 - a backend that cannot be imported
        return None, f"cannot be imported: {e}"
    why = probe(bcls)
    if why:
        return None, f"not available: {why}"
    if not has_cases:
        return None, f"{node} has no examples() to check backends with"
    return bcls, None


def _check_case(cls, bcls, params: dict, inputs: dict, tol: dict) -> tuple[bool, str]:
    """(ok, message) of backend ``bcls`` against the reference on one example."""
    try:
        p = cls.Params.model_validate(params)
        ref = _normalise(cls, cls(p, Context()).compute(**inputs))
    except Exception as e:  # noqa: BLE001
        return False, f"the reference raised {type(e).__name__}: {e}"
    try:
        got = _normalise(cls, bcls(p, Context()).compute(**inputs))
    except Exception as e:  # noqa: BLE001
        return False, f"raised {type(e).__name__}: {e}"
    msgs = []
    for port, pt in cls.out_ports.items():
        if not isinstance(got, dict) or port not in got:
            msgs.append(f"output '{port}' missing")
            continue
        m = _compare(pt.type, ref[port], got[port], tol["rtol"], tol["atol"], tol["bad_fraction"])
        if m:
            msgs.append(f"output '{port}': {m}")
    return not msgs, "; ".join(msgs) or "ok"


def _provider_matches(provider: str, plugin: str) -> bool:
    norm = lambda s: s.lower().replace("_", "-")  # noqa: E731
    return norm(provider) == norm(plugin) or norm(provider) == norm(f"GRAPHKIT_PLUGINS:{plugin}")


def _check_known(reg: Registry, nodes: list[str] | None) -> None:
    from .errors import UsageError

    unknown = [n for n in nodes or () if n not in reg.nodes]
    if unknown:
        from .suggest import did_you_mean

        raise UsageError(f"unknown node type '{unknown[0]}'{did_you_mean(unknown[0], reg.nodes)}")


def check_backends(reg: Registry, plugin: str | None = None, nodes: list[str] | None = None) -> list[Finding]:
    """Conformance findings for every registered backend, or only those that ``plugin`` (a
    distribution name, or a GRAPHKIT_PLUGINS module) provides, optionally for ``nodes`` only."""
    from .errors import UsageError

    _check_known(reg, nodes)
    pairs = sorted((node, b, e.provider) for node, per in reg.backends.items() for b, e in per.items()
                   if not nodes or node in nodes)
    if plugin:
        chosen = [p for p in pairs if _provider_matches(p[2], plugin)]
        if not chosen:
            have = sorted({p[2] for p in pairs})
            raise UsageError(f"no backends from plugin '{plugin}'"
                             + (f" (plugins with backends: {', '.join(have)})" if have else " (no plugin provides backends)"))
        pairs = chosen
    by_node: dict[str, list[str]] = {}
    for node, b, _ in pairs:
        by_node.setdefault(node, []).append(b)
    findings = []
    for node, bs in by_node.items():
        try:
            findings.extend(check_node(reg, node, bs))
        except Exception as e:  # noqa: BLE001 - the node type itself cannot be imported
            findings.extend(Finding(node, b, -1, False, f"node type cannot be loaded: {e}", checked=False) for b in bs)
    return findings


# --------------------------------------------------------------------------------------------
# declared port constraints (graphkit.contract): each one refuses a value that breaks it

CONTRACT = "contract"  # the Finding.backend of a constraint check


def check_contract(reg: Registry, node: str) -> list[Finding]:
    """For every constraint ``node`` declares, feed it a value that breaks it (made from the
    node's first example that connects the port, else from a small value the constraints
    allow) and check that it is refused as the engine refuses it: a BadInput naming the port."""
    cls = reg.node_class(node)
    findings = []
    for name in cls.constrained_ports:
        port = cls.in_ports[name]
        case, params, inputs = _base_case(cls, name)
        for rule in port.constraints.rules():
            what = f"port '{name}': {rule.describe()}"
            if inputs is None:
                findings.append(Finding(node, CONTRACT, -1, False, f"{what}: no example connects it and "
                                        f"no {port.type} can be made to break it from", checked=False))
                continue
            bad = _spoil(rule, port, inputs[name], inputs)
            refused = _refusal(cls, params, {**inputs, name: bad}, name)
            findings.append(Finding(node, CONTRACT, case, refused is None,
                                    f"{what}: refused" if refused is None else f"{what}: {refused}"))
    return findings


def check_contracts(reg: Registry, plugin: str | None = None, nodes: list[str] | None = None) -> list[Finding]:
    """:func:`check_contract` for every node type (or those ``plugin`` provides, or ``nodes``)."""
    _check_known(reg, nodes)
    names = [n for n in reg.node_names() if (not nodes or n in nodes)
             and (not plugin or _provider_matches(reg.nodes[n].provider, plugin))]
    findings = []
    for n in names:
        try:
            findings += check_contract(reg, n)
        except Exception as e:  # noqa: BLE001 - the node type cannot be imported
            findings.append(Finding(n, CONTRACT, -1, False, f"node type cannot be loaded: {e}", checked=False))
    return findings


def conform(reg: Registry, plugin: str | None = None, nodes: list[str] | None = None) -> list[Finding]:
    """What ``graphkit conform`` checks: the backends (:func:`check_backends`) and the declared
    constraints (:func:`check_contracts`) of every node type, or of those ``plugin`` provides
    (a UsageError when it provides neither backends nor constrained ports), or of ``nodes``."""
    from .errors import UsageError

    contracts = check_contracts(reg, plugin=plugin, nodes=nodes)
    try:
        return check_backends(reg, plugin=plugin, nodes=nodes) + contracts
    except UsageError:
        if not contracts:
            raise
        return contracts


def _spoil(rule, port, value, inputs):
    from .contract import MinItems

    if port.variadic and not isinstance(rule, MinItems):
        return [rule.spoil(value[0], inputs)] + list(value[1:])
    return rule.spoil(value, inputs)


def _refusal(cls, params: dict, inputs: dict, port: str) -> str | None:
    """None when the engine refuses ``inputs`` with exit 2 naming ``port``, else what happened."""
    from .contract import check_inputs
    from .errors import BadInput

    try:  # in the engine's order: the declared constraints (before params: a made-up case has none)
        check_inputs(cls, inputs)
        cls(cls.Params.model_validate(params), Context()).compute(**inputs)
    except BadInput as e:
        if e.port == port and e.exit_code == 2:
            return None
        return f"refused naming port '{e.port}' instead: {e.message}"
    except Exception as e:  # noqa: BLE001
        return f"not refused: compute raised {type(e).__name__}: {e}"
    return "accepted a value that breaks it"


def _base_case(cls, port: str) -> tuple[int, dict, dict | None]:
    """(example index, params, inputs) with ``port`` connected: the node's first example that
    connects it (and the port its ``same_size_as`` names, if one does: that rule applies only
    then), else (-1, {}, inputs made from the constraints) or (-1, {}, None)."""
    p = cls.in_ports[port]
    other = p.constraints.same_size_as
    cases = [(i, params, inputs) for i, (params, inputs) in enumerate(cls.examples()) if inputs.get(port) is not None]
    if cases:
        return next((c for c in cases if not other or c[2].get(other) is not None), cases[0])
    made = {port: _make(p)}
    if other:
        made[other] = _make(cls.in_ports[other])
    return -1, {}, None if any(v is None for v in made.values()) else made


def _make(port) -> object | None:
    """A small value of ``port``'s type that its constraints allow (None: none can be made)."""
    from .contract import Bound
    from .types import ARRAY, IMAGE, MASK, MESH, SCALAR, SPECTRUM, VECTOR, Camera, Image, Mask, Spectrum, port_type

    c = port.constraints
    x = 0.5
    for r in c.rules():
        if isinstance(r, Bound):  # inside every bound: 0.5 moved past each one by 0.25
            x = max(x, r.limit + 0.25) if r.op in ("ge", "gt") else min(x, r.limit - 0.25)
    makers = {IMAGE: lambda: Image(np.full((4, 4, (c.channels or (3,))[0]), x, np.float32)),
              MASK: lambda: Mask(np.full((4, 4), x, np.float32)), SCALAR: lambda: x,
              VECTOR: lambda: np.full(4, x), ARRAY: lambda: np.full((4, 4), x),
              SPECTRUM: lambda: Spectrum(np.linspace(400.0, 700.0, 4), np.full(4, x)),
              MESH: _unit_box,
              port_type(Camera): lambda: Camera(width=4, height=4, fx=4.0, fy=4.0, cx=2.0, cy=2.0)}
    make = makers.get(port.type)
    if make is None:
        return None
    return [make()] * max(1, c.min_items or 1) if port.variadic else make()


def _unit_box():
    import trimesh

    return trimesh.creation.box()
