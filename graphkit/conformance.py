"""Backend conformance harness: every registered backend of a node type must agree with the
node's own (numpy reference) compute on the node's ``examples()``, within the node's
``tolerance``: ``rtol``/``atol`` per value, and ``bad_fraction``, the share of values allowed
outside them (rasterisers disagree on silhouette pixels).  Tests call :func:`check_node` for
every node type that has backends.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .node import Context, probe
from .registry import NUMPY, Registry
from .store import value_parts


@dataclass
class Finding:
    node: str
    backend: str
    case: int
    ok: bool
    message: str


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


def check_node(reg: Registry, node: str) -> list[Finding]:
    """Run every available non-reference backend of ``node`` against the reference."""
    cls = reg.node_class(node)
    findings = []
    cases = cls.examples()
    for bname in reg.backend_names(node):
        if bname == NUMPY:
            continue
        bcls = reg.backend_class(node, bname)
        why = probe(bcls)
        if why:
            findings.append(Finding(node, bname, -1, False, f"not available: {why}"))
            continue
        if not cases:
            findings.append(Finding(node, bname, -1, False, f"{node} has no examples() to check backends with"))
            continue
        tol = {"rtol": 1e-5, "atol": 1e-6, "bad_fraction": 0.0, **cls.tolerance, **getattr(bcls, "tolerance", {})}
        for i, (params, inputs) in enumerate(cases):
            p = cls.Params.model_validate(params)
            ref = _normalise(cls, cls(p, Context()).compute(**inputs))
            got = _normalise(cls, bcls(p, Context()).compute(**inputs))
            msgs = []
            for port, pt in cls.out_ports.items():
                m = _compare(pt.type, ref[port], got[port], tol["rtol"], tol["atol"], tol["bad_fraction"])
                if m:
                    msgs.append(f"output '{port}': {m}")
            findings.append(Finding(node, bname, i, not msgs, "; ".join(msgs) or "ok"))
    return findings
