"""Nothing changes for users (issue 25): every graph in graphs/ gives the same bytes and the same
cache keys as main did before the restructuring, as recorded in tests/data/main_digests.json
(see tests/data/record_digests.py: what is recorded, from which commit, when it may be
re-recorded, and why the graphs run with numpy, OpenBLAS and OpenCV pinned to their x86-64-v3
kernels).

By default the graphs run in one cache, room_relight cut to the outputs before its two §4.5
re-solves (``CHEAP_OUTPUTS`` there: 38 s + 50 s of compute, most of the graph's 72 s cold on 2
cores): the nodes that ran are checked for their key, their output digests and the files
written; the nodes that did not run for their key where ``graphkit status`` can tell it (every
input computed).  ``GRAPHKIT_SAME_BYTES_FULL=1`` runs
every graph whole and checks every node and file.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RECORDER = ROOT / "tests" / "data" / "record_digests.py"
RECORDED = json.loads((ROOT / "tests" / "data" / "main_digests.json").read_text())["graphs"]
FULL = os.environ.get("GRAPHKIT_SAME_BYTES_FULL") == "1"

pytestmark = pytest.mark.xdist_group("same_bytes")  # one worker runs the graphs once, in one cache


def _x86_64_v3() -> bool:
    """The CPU runs the kernels the recorder pins (AVX2, FMA, F16C: x86-64-v3)."""
    from numpy._core._multiarray_umath import __cpu_features__ as has

    return platform.machine().lower() in ("x86_64", "amd64") and all(has.get(f) for f in ("AVX2", "FMA3", "F16C"))


@pytest.fixture(scope="module")
def computed():
    """The graphs' digests now, from the recorder (its pinned environment) in a fresh process."""
    if not _x86_64_v3():
        pytest.skip(reason="the digests were recorded with x86-64-v3 (AVX2) kernels: other CPUs give other last bits")
    env = {k: v for k, v in os.environ.items() if not k.startswith("GRAPHKIT_")}
    r = subprocess.run([sys.executable, RECORDER, "--print", *sorted(RECORDED), *(["--full"] if FULL else [])],
                       capture_output=True, text=True, env=env, cwd=ROOT, timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)


def test_every_graph_is_recorded():
    assert sorted(p.stem for p in (ROOT / "graphs").glob("*.yaml")) == sorted(RECORDED), \
        "a graph was added or removed: record its digests (tests/data/record_digests.py, with the reason)"


def differences(want: dict, got: dict) -> list[str]:
    """What ``got`` (one graph's digests now) changes from ``want`` (as recorded); every node and
    file of a graph that ran whole (not ``cut_to`` some outputs) must be there."""
    whole, bad = got["cut_to"] is None, []
    if set(got["nodes"]) != set(want["nodes"]):
        bad.append(f"nodes {sorted(set(want['nodes']) ^ set(got['nodes']))} added or removed")
    for n in sorted(set(got["nodes"]) & set(want["nodes"])):
        w, g = want["nodes"][n], got["nodes"][n]
        if w["key"] is not None and g["key"] is not None and g["key"] != w["key"]:
            bad.append(f"node {n}: cache key {g['key']}, recorded {w['key']}")
        if "outputs" in g and g["outputs"] != w["outputs"]:
            bad.append(f"node {n}: output digests {g['outputs']}, recorded {w['outputs']}")
        if whole and ("outputs" not in g or g["key"] is None):
            bad.append(f"node {n}: did not run in a whole run")
    for f in sorted(got["files"]):
        if got["files"][f] != want["files"].get(f):
            bad.append(f"file {f}: xxh3 {got['files'][f]}, recorded {want['files'].get(f)}")
    if whole and set(got["files"]) != set(want["files"]):
        bad.append(f"files {sorted(set(want['files']) - set(got['files']))} not written")
    return bad


@pytest.mark.parametrize("graph", sorted(RECORDED))
def test_same_keys_and_bytes_as_main(graph, computed):
    got, want = computed[graph], RECORDED[graph]
    bad = differences(want, got)
    assert not bad, (f"{graph} no longer computes what main did (a node whose output changes on purpose "
                     "bumps its version and the digests are re-recorded with the reason):\n  " + "\n  ".join(bad))


def test_a_changed_byte_is_found():
    """The comparison itself: a changed key, output digest or file digest is each reported."""
    want = RECORDED["quickstart"]
    got = json.loads(json.dumps(want))
    assert differences(want, got) == []
    node = sorted(got["nodes"])[0]
    got["nodes"][node]["key"] = "0" * 32
    port = sorted(got["nodes"][node]["outputs"])[0]
    got["nodes"][node]["outputs"][port] = "1" * 32
    got["files"][sorted(got["files"])[0]] = "2" * 32
    bad = differences(want, got)
    assert len(bad) == 3 and all(s.startswith(("node", "file")) for s in bad), bad
