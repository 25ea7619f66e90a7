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
        try:
            bcls = reg.backend_class(node, bname)
        except Exception as e:  # noqa: BLE001 - a backend that cannot be imported
            findings.append(Finding(node, bname, -1, False, f"cannot be imported: {e}", checked=False))
            continue
        why = probe(bcls)
        if why:
            findings.append(Finding(node, bname, -1, False, f"not available: {why}", checked=False))
            continue
        if not cases:
            findings.append(Finding(node, bname, -1, False, f"{node} has no examples() to check backends with",
                                    checked=False))
            continue
        tol = {**DEFAULT_TOLERANCE, **cls.tolerance, **getattr(bcls, "tolerance", {})}
        for i, (params, inputs) in enumerate(cases):
            try:
                p = cls.Params.model_validate(params)
                ref = _normalise(cls, cls(p, Context()).compute(**inputs))
            except Exception as e:  # noqa: BLE001
                findings.append(Finding(node, bname, i, False, f"the reference raised {type(e).__name__}: {e}"))
                continue
            try:
                got = _normalise(cls, bcls(p, Context()).compute(**inputs))
            except Exception as e:  # noqa: BLE001
                findings.append(Finding(node, bname, i, False, f"raised {type(e).__name__}: {e}"))
                continue
            msgs = []
            for port, pt in cls.out_ports.items():
                if not isinstance(got, dict) or port not in got:
                    msgs.append(f"output '{port}' missing")
                    continue
                m = _compare(pt.type, ref[port], got[port], tol["rtol"], tol["atol"], tol["bad_fraction"])
                if m:
                    msgs.append(f"output '{port}': {m}")
            findings.append(Finding(node, bname, i, not msgs, "; ".join(msgs) or "ok"))
    return findings


def _provider_matches(provider: str, plugin: str) -> bool:
    norm = lambda s: s.lower().replace("_", "-")  # noqa: E731
    return norm(provider) == norm(plugin) or norm(provider) == norm(f"GRAPHKIT_PLUGINS:{plugin}")


def check_backends(reg: Registry, plugin: str | None = None, nodes: list[str] | None = None) -> list[Finding]:
    """Conformance findings for every registered backend, or only those that ``plugin`` (a
    distribution name, or a GRAPHKIT_PLUGINS module) provides, optionally for ``nodes`` only."""
    from .errors import UsageError

    pairs = sorted((node, b, e.provider) for node, per in reg.backends.items() for b, e in per.items())
    if nodes:
        unknown = [n for n in nodes if n not in reg.nodes]
        if unknown:
            from .suggest import did_you_mean

            raise UsageError(f"unknown node type '{unknown[0]}'{did_you_mean(unknown[0], reg.nodes)}")
        pairs = [p for p in pairs if p[0] in nodes]
    if plugin:
        chosen = [p for p in pairs if _provider_matches(p[2], plugin)]
        if not chosen:
            have = sorted({p[2] for p in pairs})
            raise UsageError(f"no backends from plugin '{plugin}'"
                             + (f" (plugins with backends: {', '.join(have)})" if have else " (no plugin provides backends)"))
        pairs = chosen
    findings = []
    by_node: dict[str, list[str]] = {}
    for node, b, _ in pairs:
        by_node.setdefault(node, []).append(b)
    for node, bs in by_node.items():
        try:
            findings.extend(check_node(reg, node, bs))
        except Exception as e:  # noqa: BLE001 - the node type itself cannot be imported
            findings.extend(Finding(node, b, -1, False, f"node type cannot be loaded: {e}", checked=False) for b in bs)
    return findings
