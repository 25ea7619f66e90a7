"""Record (or print) every graph's cache keys and output bytes, for tests/test_same_bytes.py.

``main_digests.json`` next to this file was recorded from main at commit 3bc3482 (before the
restructuring of issue 25): for each graph in graphs/, every node's cache key and the digests
of its output values (as manifest.json records them), and every file the graph writes into
``--out`` by its xxh3-128 (manifest.json's ``files``; report.html is left out, it holds
timings and the host name).  The test proves against it that the engine and the nodes still
compute the same bytes and the same keys.

Regenerate it only for a stated reason, named in the commit message: a node's ``version``
bumped because its output changes on purpose, a graph in graphs/ added or edited, or a pinned
dependency in constraints.txt upgraded (numpy, OpenBLAS, OpenCV, mediapipe, OpenImageIO may
change last bits).  Never to make the test pass after a change that was meant to keep the bytes:

    .venv/bin/python tests/data/record_digests.py          # whole graphs (a few minutes)

Machine: numpy, OpenBLAS and OpenCV pick their SIMD kernels by the CPU, and float results then
differ in the last bits between CPUs with and without AVX-512 (measured on main: blush's
SkinChromophores and everything after it, face_capture's probe and fit).  So this script pins
those libraries to their x86-64-v3 (AVX2 + FMA) kernels through ``PINNED_ENV``, set before
anything imports numpy: every x86-64-v3 CPU, Intel or AMD, computes the same bytes then.
Checked on main: the pinned run on an AVX-512 AMD EPYC gives the same bytes as an unpinned run
under ``qemu-x86_64 -cpu Haswell`` (an AVX2 CPU; blush and makeup, every node and file), and as
a second pinned run (every graph).  OpenCV's wheels also carry Intel's IPP, which picks its own
kernels by the CPU and does not read ``OPENCV_CPU_DISABLE``: on an Intel Xeon with AVX-512
(Sapphire Rapids) it ran its AVX-512 kernels (k0) where the AMD EPYCs ran its AVX2 ones (l9),
and ``cv2.resize``'s bilinear enlargement of float32 (SmoothFill's outward blurs, so
CompositeFace's portraits in face_relight, face_environment and face_soft_shadows) gave other
last bits; ``OPENCV_IPP=avx2`` holds it to l9 (checked there: every graph the same bytes as
recorded, and under ``qemu-x86_64 -cpu Haswell`` the same SmoothFill bytes).  mediapipe's FaceMesh (TFLite) gave the same landmarks there
too.

A glob sweep passes the absolute path of each file it matches as a param (makeup_batch's
LoadImage), so its keys, and the provenance in its saved files, depend on where graphs/ lies.
The graphs are therefore always run from a copy at one fixed place, ``FIXED`` (under a lock, so
two checkouts on one machine take turns): the same keys and bytes from any checkout.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

PINNED_ENV = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL",  # numpy 2.x dispatch groups above x86-64-v3
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENCV_CPU_DISABLE": "AVX512F,AVX512-SKX,AVX512-COMMON,AVX512-ICL,AVX512-CLX,AVX512-CNL",
    "OPENCV_IPP": "avx2",  # the Intel IPP inside OpenCV's wheels: its AVX2 kernels (l9), not k0 (AVX-512)
}
os.environ.update(PINNED_ENV)  # before numpy is imported (graphkit is imported inside functions)

ROOT = Path(__file__).resolve().parents[2]
GRAPHS = ROOT / "graphs"
DATA = Path(__file__).resolve().parent / "main_digests.json"
FIXED = Path("/tmp/graphkit-same-bytes")  # where the graphs run from (see the module docstring)
# graph -> the outputs its cheap check runs (the others run whole): room_relight's two §4.5
# re-solves (virtual light 38 s, virtual box 50 s of compute, measured on 2 cores) are left out;
# their keys are still checked
CHEAP_OUTPUTS = {"room_relight": ["photo", "no_shadows", "light_a_off", "light_b_double", "reprojected",
                                  "lights"]}


def _cli(*args) -> str:
    """``graphkit ARGS`` in this process; its stdout (a failure raises with its stderr)."""
    from graphkit.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    if code != 0:
        raise RuntimeError(f"graphkit {' '.join(map(str, args))}: exit {code}\n{err.getvalue()[-3000:]}")
    return out.getvalue()


def _keys(graph: Path, cache: Path) -> dict[str, str | None]:
    """Every node's key as `graphkit status` gives it (None while an upstream node would run)."""
    return {n["node"]: n["key"] for n in json.loads(_cli("status", graph, "--cache", cache, "--json"))["nodes"]}


def digests(graph: Path, cache: Path, out: Path, outputs: list[str] | None = None) -> dict:
    """Run ``graph`` (only ``outputs`` when given) and return its keys, output and file digests:
    ``{"nodes": {node: {"key": …, "outputs": {port: digest}}}, "files": {name: xxh3}, "cut_to":
    outputs}``; a node
    that did not run has no ``outputs`` (and its key when an upstream node did not run either)."""
    _cli("run", graph, "--cache", cache, "--out", out, "-q", "--jobs", "2",
         *(a for o in outputs or [] for a in ("--output", o)))
    manifest = json.loads((out / "manifest.json").read_text())
    nodes = {n: {"key": k} for n, k in _keys(graph, cache).items()}
    for n, rec in manifest["nodes"].items():
        nodes[n]["outputs"] = rec["outputs"]
    files = {f: d["xxh3"] for f, d in manifest["files"].items() if f != "report.html"}
    return {"nodes": nodes, "files": files, "cut_to": outputs}


def collect(names: list[str], cheap: bool, work: Path) -> dict:
    """The digests of the graphs ``names``, run from the copy of graphs/ at ``FIXED`` with one
    cache (shared nodes run once)."""
    import fcntl

    with open(f"{FIXED}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        shutil.rmtree(FIXED, ignore_errors=True)
        graphs = shutil.copytree(GRAPHS, FIXED / "graphs")
        try:
            return {g: digests(graphs / f"{g}.yaml", work / "cache", work / "out" / g,
                               CHEAP_OUTPUTS.get(g) if cheap else None) for g in names}
        finally:
            shutil.rmtree(FIXED, ignore_errors=True)


def record() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        data = collect(sorted(p.stem for p in GRAPHS.glob("*.yaml")), cheap=False, work=Path(tmp))
    return {"commit": _commit(), "pinned_env": PINNED_ENV, "graphs": data}


def _commit() -> str:
    """The checkout's commit, marked '+edits' when what computes the graphs differs from it."""
    import subprocess

    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()

    edited = git("status", "--porcelain", "--", "graphkit", "nodes", "plugins", "shaders", "graphs")
    return git("rev-parse", "--short", "HEAD") + ("+edits" if edited else "")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--print", dest="names", nargs="+", metavar="GRAPH",
                   help="print these graphs' digests as JSON instead of recording all of them")
    p.add_argument("--full", action="store_true", help="with --print: run every graph whole")
    args = p.parse_args(argv)
    if args.names:
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(collect(args.names, cheap=not args.full, work=Path(tmp))))
        return 0
    DATA.write_text(json.dumps(record(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {DATA}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
