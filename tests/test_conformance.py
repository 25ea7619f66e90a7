"""Backend conformance: every registered non-numpy backend of every node type agrees with the
node's numpy reference on the node's ``examples()``, within the node's ``tolerance``.

A backend that is not available here fails (with its reason) instead of being skipped: CI
installs what every registered backend needs (pocl for ``opencl``), so "unavailable" is a
broken set-up, not a reason to stop checking.
"""
from __future__ import annotations

import functools

import pytest

from graphkit.conformance import check_node
from graphkit.registry import default_registry


def _pairs() -> list[tuple[str, str]]:
    reg = default_registry()
    return sorted((node, b) for node, per in reg.backends.items() for b in per)


@functools.lru_cache(maxsize=None)
def _findings(node: str):
    return tuple(check_node(default_registry(), node))


def test_registry_has_no_problems():
    # a plugin that failed to import, or a backend registered twice, would silently shrink the
    # set of backends checked below
    assert default_registry().problems == []


def test_opencl_backend_is_discovered():
    # the harness below must not pass vacuously: the plugin's entry point is found
    reg = default_registry()
    assert "opencl" in reg.backend_names("RatioImage"), (
        "RatioImage has no 'opencl' backend: is plugins/graphkit-opencl installed (make / pip install -e)?")
    assert ("RatioImage", "opencl") in _pairs()
    assert reg.backends["RatioImage"]["opencl"].provider == "graphkit-opencl"


@pytest.mark.parametrize(("node", "backend"), _pairs(), ids=[f"{n}-{b}" for n, b in _pairs()])
def test_backend_matches_reference(node, backend):
    reg = default_registry()
    assert node in reg.nodes, f"backend '{backend}' is registered for unknown node type '{node}'"
    mine = [f for f in _findings(node) if f.backend == backend]
    assert mine, f"check_node reported nothing for {node}/{backend}"
    bad = [f"case {f.case}: {f.message}" for f in mine if not f.ok]
    assert not bad, f"{node}/{backend} disagrees with the numpy reference or cannot run:\n" + "\n".join(bad)
    # at least one real comparison (case >= 0) ran
    assert any(f.case >= 0 for f in mine)
