"""The OpenCL backends of KMStack, LocalHistMatch, SkinShade, CosmeticShade and Relight
(plugins/graphkit-opencl) beyond the conformance harness (tests/test_conformance.py runs them
on each node's examples()):

* the examples really exercise every kernel: a planted bug in each kernel source is caught;
* the copying path used for GPUs (no host-memory buffers, one pixel per work item) conforms;
* bad input: a device without double precision, a device too small for the image, an OpenCL
  allocation failure — a preferred backend falls back to numpy with one notice, a pinned one
  is exit 2 naming the node, the backend and the reason;
* a backend that declines preference on a CPU device keeps numpy under --backend, runs when
  pinned;
* one context, queue and program cache per device, shared by every node and every run of a
  process (the studio's frames); the manifest names the device of every OpenCL node.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from graphkit.conformance import check_node
from graphkit.registry import default_registry

NEW = ("KMStack", "LocalHistMatch", "SkinShade", "CosmeticShade", "Relight")


def _bad(node):
    return [f"case {f.case}: {f.message}" for f in check_node(default_registry(), node)
            if f.backend == "opencl" and not f.ok]


def test_backends_registered():
    reg = default_registry()
    for n in NEW + ("RatioImage",):
        assert "opencl" in reg.backend_names(n), n
        assert reg.backends[n]["opencl"].provider == "graphkit-opencl"


# (kernel file, text to replace, planted bug, node whose examples must catch it)
MUTANTS = [
    ("opencl/km_lookup.cl", "acc[1].xyz * g", "acc[1].xyz * g * 0.9f", "KMStack"),
    # the fast grid shifted by half a cell (issue 10: the numpy tests let this pass)
    ("opencl/histmatch.cl", "float fx = (float)(2 * x + 1 - c) * inv2c;",
     "float fx = (float)(2 * x + 1) * inv2c;", "LocalHistMatch"),
    ("opencl/sss.cl", "q[j] *= e2[j];", "", "SkinShade"),
    ("opencl/sss.cl", "float out = (wsum[j] > 1e-12f * norm[j]) ? acc[j] / wsum[j] : self;",
     "float out = acc[j];", "CosmeticShade"),
    ("opencl/relight.cl", "ratio += R[qs] * e[s * 3 + c];", "ratio += R[qs] * e[c];", "Relight"),
    ("opencl/relight.cl", "out[o + c] = base[q] * ratio + glow;", "out[o + c] = base[q] * ratio;", "Relight"),
]


@pytest.mark.parametrize(("shader", "old", "new", "node"), MUTANTS,
                         ids=[f"{m[3]}-{i}" for i, m in enumerate(MUTANTS)])
def test_planted_kernel_bug_is_caught(shader, old, new, node, monkeypatch):
    import graphkit.resources as res
    from graphkit_opencl.runtime import runtime

    src = res.shader_source(shader)
    assert old in src, f"{shader} no longer holds {old!r}: update the mutant"
    real = res.shader_source
    monkeypatch.setattr(res, "shader_source", lambda rel: src.replace(old, new) if rel == shader else real(rel))
    monkeypatch.setattr(runtime(), "programs", {})  # build the mutant (the real programs come back after)
    assert _bad(node), f"a planted bug in {shader} ({new!r}) passes {node}'s conformance examples"


def test_gpu_path_conforms(monkeypatch):
    """On a GPU the buffers are copied and SSS runs one pixel per work item: force that path."""
    from graphkit_opencl.runtime import Runtime

    from graphkit.conformance import _compare, _normalise

    monkeypatch.setattr(Runtime, "host_memory", property(lambda self: False))
    monkeypatch.setattr(Runtime, "is_cpu", property(lambda self: False))
    reg = default_registry()
    # one case per kernel variant: KM over an RGB background, histmatch's grid path, SSS with
    # per-pixel σ and a mask, Relight
    for n, case in (("KMStack", 1), ("LocalHistMatch", 4), ("SkinShade", 1), ("Relight", 1)):
        cls, bcls = reg.node_class(n), reg.backend_class(n, "opencl")
        params, inputs = cls.examples()[case]
        p = cls.Params.model_validate(params)
        ref, got = _normalise(cls, cls(p).compute(**inputs)), _normalise(cls, bcls(p).compute(**inputs))
        tol = {**cls.tolerance, **getattr(bcls, "tolerance", {})}
        for port, pt in cls.out_ports.items():
            assert _compare(pt.type, ref[port], got[port], tol["rtol"], tol["atol"]) is None, (n, port)


# ---------------------------------------------------------------------------------------------
# bad input, through the CLI in this process (the device is patched, the kernels are real)

GRAPH = """\
graphkit: 1
name: bad_{tag}
nodes:
  hn:
    type: LoadImage
    params: {{path: hn.exr}}
  ht:
    type: LoadImage
    params: {{path: ht.exr}}
  match:
    type: LocalHistMatch
    inputs: {{neutral: hn.image, target: ht.image}}
    params: {{radius: 16.0, stats_size: 0}}
{pin}  save:
    type: SaveImage
    inputs: {{image: match.matched}}
    params: {{path: m.exr, bits: 32}}
outputs: {{m: save.file}}
"""


@pytest.fixture(scope="module")
def maps_dir(tmp_path_factory):
    import OpenImageIO as oiio

    d = tmp_path_factory.mktemp("opencl_bad")
    rng = np.random.default_rng(3)
    for name, scale in (("hn", 0.1), ("ht", 0.2)):
        px = (rng.random((96, 128, 1)) * scale).astype(np.float32)
        out = oiio.ImageOutput.create(str(d / f"{name}.exr"))
        out.open(str(d / f"{name}.exr"), oiio.ImageSpec(128, 96, 1, "float"))
        out.write_image(px)
        out.close()
    for tag, pin in (("free", ""), ("pinned", "    backend: opencl\n")):
        (d / f"{tag}.yaml").write_text(GRAPH.format(tag=tag, pin=pin))
    return d


def _cli(capsys, graph, tmp_path, *args):
    from graphkit.cli import main

    capsys.readouterr()
    code = main(["run", str(graph), "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out"),
                 "-q", "-j", "1", *args])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def _backend_of(tmp_path, node="match"):
    m = json.loads((tmp_path / "out" / "manifest.json").read_text())
    return m["nodes"][node]["backend"], m["nodes"][node]["backend_version"]


def test_device_without_fp64(maps_dir, tmp_path, capsys, monkeypatch):
    from graphkit_opencl.runtime import Runtime

    monkeypatch.setattr(Runtime, "has_fp64", property(lambda self: False))
    code, err = _cli(capsys, maps_dir / "free.yaml", tmp_path, "--backend", "opencl")
    assert code == 0, err
    notices = [ln for ln in err.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1 and "cl_khr_fp64" in notices[0] and "using numpy" in notices[0], err
    assert _backend_of(tmp_path)[0] == "numpy"
    code, err = _cli(capsys, maps_dir / "pinned.yaml", tmp_path / "p")
    assert code == 2, err
    assert "'match'" in err and "opencl" in err and "double precision" in err, err
    # KMStack's kernels need no double: still available
    assert default_registry().backend_class("KMStack", "opencl").available()


def test_device_too_small_for_the_image(maps_dir, tmp_path, capsys, monkeypatch):
    from graphkit_opencl import base
    from graphkit_opencl.histmatch import LocalHistMatchOpenCL

    monkeypatch.setattr(LocalHistMatchOpenCL, "cpu_note", None)  # preferred, as on a GPU
    monkeypatch.setattr(base, "device_limits", lambda rt: (16 << 10, 64 << 10))  # 16 KiB buffers
    code, err = _cli(capsys, maps_dir / "free.yaml", tmp_path, "--backend", "opencl")
    assert code == 0, err
    notices = [ln for ln in err.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1, err
    assert "cannot run node 'match'" in notices[0] and "MiB" in notices[0] and "using numpy" in notices[0]
    backend, version = _backend_of(tmp_path)
    assert backend == "numpy" and "OpenCL" not in version  # keyed and recorded as numpy
    code, err = _cli(capsys, maps_dir / "pinned.yaml", tmp_path / "p")
    assert code == 2, err
    assert "node 'match' (LocalHistMatch)" in err and "backend 'opencl' cannot run here" in err and "MiB" in err
    assert not (tmp_path / "p" / "out" / "m.exr").exists()


def test_allocation_failure_becomes_cannot_run():
    """A real OpenCL failure: a buffer larger than the device allows."""
    from graphkit import BackendCannotRun
    from graphkit_opencl.base import cannot_run
    from graphkit_opencl.runtime import runtime

    rt = runtime()
    cl = rt.cl
    with pytest.raises(BackendCannotRun, match="ran out of memory for a test image"):
        with cannot_run(rt, "a test image"):
            b = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, int(rt.device.max_mem_alloc_size) * 4)
            cl.enqueue_fill_buffer(rt.queue, b, np.float32(0), 0, b.size).wait()


def test_no_opencl_device(maps_dir, tmp_path, capsys, monkeypatch):
    """POCL_DEVICES names no device kind pocl has: the real ICD reports no device."""
    import subprocess
    import sys

    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("GRAPHKIT_OPENCL")}
    env["POCL_DEVICES"] = "none-such"
    run = [sys.executable, "-m", "graphkit", "run", "--cache", str(tmp_path / "c"), "-q"]
    p = subprocess.run(run[:4] + [str(maps_dir / "free.yaml")] + run[4:] + ["--out", str(tmp_path / "o"),
                       "--backend", "opencl"], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    notices = [ln for ln in p.stderr.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1 and "no OpenCL device" in notices[0] and "using numpy" in notices[0], p.stderr
    p = subprocess.run(run[:4] + [str(maps_dir / "pinned.yaml")] + run[4:] + ["--out", str(tmp_path / "o2")],
                       capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert "'match'" in p.stderr and "opencl" in p.stderr and "no OpenCL device" in p.stderr


# ---------------------------------------------------------------------------------------------
# preference on a CPU device; one runtime per process; the manifest's device


def test_cpu_preference_is_honest(maps_dir, tmp_path, capsys, monkeypatch):
    from graphkit_opencl.histmatch import LocalHistMatchOpenCL
    from graphkit_opencl.runtime import runtime

    monkeypatch.setattr(LocalHistMatchOpenCL, "cpu_note", "measured slower than numpy")
    assert runtime().is_cpu
    code, err = _cli(capsys, maps_dir / "free.yaml", tmp_path, "--backend", "opencl")
    assert code == 0, err
    notices = [ln for ln in err.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1 and "not chosen by preference" in notices[0] and "measured slower" in notices[0]
    assert _backend_of(tmp_path)[0] == "numpy"
    code, err = _cli(capsys, maps_dir / "pinned.yaml", tmp_path / "p")  # a pin still runs it
    assert code == 0, err
    assert _backend_of(tmp_path / "p")[0] == "opencl"


def test_one_runtime_per_process_and_device_in_manifest(maps_dir, tmp_path, capsys):
    from graphkit_opencl.runtime import runtime

    rt = runtime()
    code, err = _cli(capsys, maps_dir / "pinned.yaml", tmp_path / "a")
    assert code == 0, err
    built = dict(rt.programs)
    backend, version = _backend_of(tmp_path / "a")
    assert backend == "opencl" and rt.describe() in version  # the manifest names the device
    # a second run (another frame in the studio): same context, queue and programs, no rebuild
    code, err = _cli(capsys, maps_dir / "pinned.yaml", tmp_path / "b")
    assert code == 0, err
    assert runtime() is rt and all(rt.programs[k] is v for k, v in built.items())
