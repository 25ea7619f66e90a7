"""Every graph in graphs/ with the OpenCL backends, against its numpy run, on the graphs' real
inputs (the astronaut's chromophore maps, the makeup library over the astronaut, the Cornell
scene): each node that has an ``opencl`` backend is pinned to it, and its outputs must agree
with the numpy run's within the node's conformance tolerance (the node's ``tolerance`` and the
backend's own, as tests/test_conformance.py uses them).  The manifest of a ``--backend
opencl`` run records, for every node, the backend that ran it and — for OpenCL nodes — the
device.

The two runs share one cache, so the nodes without an OpenCL backend are computed once.
Only the part of each graph up to its OpenCL nodes runs, and room_relight's radiosity is
solved coarser than the graph's defaults (RadiositySolve eps_bf 1.0, TextureRefine off) with
its two §4.5 nodes (virtual light / box: a host re-solve, the reference's code on both
backends) left out, to keep the suite's time; the full graphs were run with --backend opencl
for the closing note of issue 15 (benchmarks/bench_opencl.py --graphs).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphkit.conformance import _compare
from graphkit.registry import default_registry

GRAPHS = Path(__file__).resolve().parents[1] / "graphs"
# graph → {node: param overrides} and the outputs kept (None: all)
REDUCE = {
    "room_relight": ({"radiosity": {"eps_bf": 1.0, "eps_bfv": 0.1, "min_area": 0.02, "max_level": 3},
                      "refined": {"max_rounds": 0}},
                     ["light_a_off", "light_b_double", "reprojected", "no_shadows"]),
    "makeup_batch": ({}, ["made_up/astronaut"]),  # one instance of the batch: the others are the same nodes
}


def _graph(name):
    from graphkit.graphfile import load_graph

    reg = default_registry()
    g = load_graph(GRAPHS / f"{name}.yaml", reg)
    overrides, keep = REDUCE.get(name, ({}, None))
    for node, upd in overrides.items():
        gn = g.nodes[node]
        gn.params = gn.params.model_copy(update=upd)
    if keep is not None:
        g.outputs = {k: v for k, v in g.outputs.items() if k in keep}
    return g


def _run(g, cache, backends=(), targets=None):
    from graphkit.api import Run
    from graphkit.executor import run_local
    from graphkit.runner import Session
    from graphkit.store import Store

    notices = []
    s = Session(g, default_registry(), Store(cache).open(), list(backends), notice=notices.append)
    targets = sorted({n for n, _ in g.outputs.values()}) if targets is None else targets
    return Run(g, run_local(s, targets, jobs=2), s), notices


def _opencl_nodes(g):
    reg = default_registry()
    return sorted(n for n, gn in g.nodes.items() if "opencl" in reg.backend_names(gn.type))


@pytest.mark.parametrize("name", sorted(p.stem for p in GRAPHS.glob("*.yaml")))
def test_graph_with_opencl_matches_numpy(name, tmp_path):
    reg = default_registry()
    cache = tmp_path / "cache"
    g = _graph(name)
    cl_nodes = [n for n in _opencl_nodes(g) if n in g.upstream(sorted({x for x, _ in g.outputs.values()}))]
    assert cl_nodes, f"{name} has no node with an opencl backend any more"
    ref, _ = _run(g, cache, targets=cl_nodes)  # the numpy run, up to the OpenCL nodes
    g = _graph(name)
    for n in cl_nodes:
        g.nodes[n].backend = "opencl"  # pinned, as `backend: opencl` in the file
    got, _ = _run(g, cache, targets=cl_nodes)
    for n in cl_nodes:
        gn = g.nodes[n]
        assert got.result.outcomes[n].backend == "opencl" and not got.result.outcomes[n].hit, n
        bcls = reg.backend_class(gn.type, "opencl")
        tol = {"rtol": 1e-5, "atol": 1e-6, "bad_fraction": 0.0, **gn.cls.tolerance, **getattr(bcls, "tolerance", {})}
        for port, pt in gn.cls.out_ports.items():
            a, b = ref.value(f"{n}.{port}"), got.value(f"{n}.{port}")
            msg = _compare(pt.type, a, b, tol["rtol"], tol["atol"], tol["bad_fraction"])
            assert msg is None, f"{name}: node '{n}' ({gn.type}) output '{port}': {msg}"
    # preferred (--backend opencl): each node records the backend that ran it, OpenCL ones the
    # device (the manifest's backend / backend_version; tests/test_opencl_backends.py reads
    # manifest.json itself); a backend declining preference on this device says so once
    from graphkit_opencl.runtime import runtime

    run, notices = _run(_graph(name), cache, ["opencl"], targets=cl_nodes)
    dev = runtime().describe()
    for n, o in run.result.outcomes.items():
        assert o.backend in reg.backend_names(o.type), (n, o.backend)
        if o.backend == "opencl":
            assert dev in o.backend_version, (n, o.backend_version)
        elif n in cl_nodes:
            assert any(o.type in x and "not chosen by preference" in x for x in notices), (n, notices)
    assert len(notices) == len({x.split(" for ")[1].split(" ")[0] for x in notices}), notices
