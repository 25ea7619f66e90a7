"""The OpenCL runtime's device choice (plugins/graphkit-opencl/graphkit_opencl/runtime.py).

On an AMD Zen 5 machine pip's ``pocl-binary-distribution`` (LLVM 14) enumerates a CPU device
whose compiler fails on every kernel (``unknown target CPU 'generic'``), while Debian's
``pocl-opencl-icd`` builds there.  The runtime probes each candidate device (builds and runs a
small kernel) and skips those that fail with one notice line.  Two checks:

* in-process: the first candidate's compiler is made to fail with Zen 5's error (a monkeypatched
  ``Program.build``); the runtime picks the next device and says so once;
* through the CLI with the real ICDs: pip's pocl loaded from a folder without its kernel
  library (so its real compiler fails on every build) ahead of Debian's pocl; ``graphkit run``
  still runs the opencl backend, on Debian's pocl, with one notice naming the skipped platform.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ZEN5 = ("clBuildProgram failed: BUILD_PROGRAM_FAILURE - clBuildProgram failed: BUILD_PROGRAM_FAILURE\n\n"
        "Build on <pyopencl.Device 'pthread-AMD EPYC 9555 64-Core Processor'>:\n\n"
        "error: unknown target CPU 'generic'\nnote: valid target CPU values are: nocona, core2, ...\n")


@pytest.fixture
def fresh_runtime(monkeypatch):
    from graphkit_opencl import runtime as R

    monkeypatch.setattr(R, "_cache", {})
    monkeypatch.delenv(R.DEVICE_ENV, raising=False)
    monkeypatch.delenv(R.DISABLE_ENV, raising=False)
    return R


def test_platform_whose_compiler_fails_is_skipped_with_one_notice(fresh_runtime, monkeypatch, capsys):
    import pyopencl as cl

    R = fresh_runtime
    cands = R.candidates("")
    first = cands[0][1]
    real_build = cl.Program.build

    def build(self, *a, **kw):  # the compiler of the first candidate's platform fails like pip pocl on Zen 5
        if self._context.devices[0].platform == first.platform:
            raise cl.RuntimeError(ZEN5)
        return real_build(self, *a, **kw)

    monkeypatch.setattr(cl.Program, "build", build)
    others = [(i, d) for i, d in cands if d.platform != first.platform]
    if not others:  # one platform only: nothing to fall back to, and the reason is given
        with pytest.raises(R.Unavailable, match="unknown target CPU 'generic'"):
            R.runtime()
        return
    rt = R.runtime()
    assert rt.device == others[0][1] and rt.index == others[0][0]
    rt2 = R.runtime()  # made once per process: no second probe, no second notice
    assert rt2 is rt
    err = capsys.readouterr().err
    notices = [ln for ln in err.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1, err
    assert "unknown target CPU 'generic'" in notices[0]
    assert cands[0][0] in notices[0] and f"using {rt.index}" in notices[0]
    # and its kernels really run on the chosen device
    from graphkit_opencl.ratio import ratio_opencl

    a = np.full((4, 5, 3), 3.0, np.float32)
    np.testing.assert_array_equal(ratio_opencl(a, np.full((4, 5, 1), 2.0, np.float32), 1e-3), a / 2)


def test_every_device_failing_is_unavailable_with_reasons(fresh_runtime, monkeypatch):
    import pyopencl as cl

    R = fresh_runtime

    def build(self, *a, **kw):
        raise cl.RuntimeError(ZEN5)

    monkeypatch.setattr(cl.Program, "build", build)
    with pytest.raises(R.Unavailable) as e:
        R.runtime()
    msg = str(e.value)
    assert msg.startswith("no OpenCL device can run kernels here")
    assert msg.count("unknown target CPU 'generic'") == len(R.candidates(""))


def test_device_list_is_an_ordered_preference(fresh_runtime):
    R = fresh_runtime
    devs = R.list_devices()
    idx = [i for i, _ in devs]
    # an explicit list is kept in its order; a type matches every device of it
    assert [i for i, _ in R.candidates(",".join(reversed(idx)))] == list(reversed(idx))
    assert {i for i, _ in R.candidates("cpu")} <= set(idx)
    with pytest.raises(R.Unavailable, match="matches no OpenCL device"):
        R.candidates("no-such-device-anywhere")
    # unset: every device, fastest first (GPU > accelerator > CPU, then units x clock)
    ranks = [R.speed_rank(d) for _, d in R.candidates("")]
    assert ranks == sorted(ranks, reverse=True)


# ---------------------------------------------------------------------------------------------
# the real ICDs: pip's pocl with a compiler that cannot build, ahead of Debian's pocl

DEBIAN_POCL = Path("/usr/lib/x86_64-linux-gnu/libpocl.so.2")

GRAPH = """\
graphkit: 1
name: ratio_icd
nodes:
  photo:
    type: LoadImage
    params: {path: "builtin:astronaut"}
  ratio:
    type: RatioImage
    inputs: {a: photo.image, b: photo.image}
    params: {eps: 0.05}
  save:
    type: SaveImage
    inputs: {image: ratio.ratio}
    params: {path: ratio.exr, bits: 32}
outputs: {ratio: save.file}
"""


def _pip_pocl() -> tuple[Path, Path]:
    """pyopencl wheel's bundled pocl library (pip's pocl) and the hwloc it links to."""
    import pyopencl

    libs = Path(pyopencl.__file__).parent / ".libs"
    pocl = sorted(libs.glob("libpocl*.so*"))
    hw = sorted((libs.parent.parent / "pocl_binary_distribution" / ".libs").glob("libhwloc*.so*"))
    if not pocl or not hw:
        pytest.fail(f"pip's pocl is not where pyopencl's wheel puts it ({libs}): is pocl-binary-distribution installed?")
    return pocl[0], hw[0]


def _env(tmp_path: Path) -> dict:
    """OCL_ICD_VENDORS with pip's pocl loaded through a folder that lacks its kernel library
    (``../../pocl_binary_distribution/.libs/share/pocl`` relative to the library is missing, so
    its compiler fails on every program: the same effect as Zen 5's unknown CPU) and Debian's pocl."""
    if not DEBIAN_POCL.exists():
        pytest.skip(reason="Debian's pocl-opencl-icd is not installed (the Makefile's sysdeps installs it)")
    pocl, hw = _pip_pocl()
    lib = tmp_path / "broken" / "lib"
    lib.mkdir(parents=True)
    (lib / pocl.name).symlink_to(pocl)
    (lib / hw.name).symlink_to(hw)
    vendors = tmp_path / "vendors"
    vendors.mkdir()
    (vendors / "pip-pocl.icd").write_text(f"{lib / pocl.name}\n")
    (vendors / "debian-pocl.icd").write_text(f"{DEBIAN_POCL}\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("GRAPHKIT_OPENCL", "OCL_ICD", "POCL_"))}
    env["OCL_ICD_VENDORS"] = str(vendors)
    # a fresh kernel cache: no binary cached by the working pip pocl can stand in for a build
    env["POCL_CACHE_DIR"] = str(tmp_path / "pocl-cache")
    return env


def _listing(env) -> list[tuple[str, str]]:
    code = ("from graphkit_opencl.runtime import list_devices, describe_device\n"
            "for i, d in list_devices(): print(i, '|', describe_device(d))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    return [tuple(s.strip() for s in ln.split("|", 1)) for ln in p.stdout.splitlines() if "|" in ln]


def _run(graph, out, cache, env, *args):
    return subprocess.run([sys.executable, "-m", "graphkit", "run", str(graph), "--cache", str(cache),
                           "--out", str(out), "-q", *args], capture_output=True, text=True, env=env, timeout=300)


def test_real_icd_pip_pocl_that_cannot_build_is_skipped(tmp_path):
    env = _env(tmp_path)
    devs = _listing(env)
    debian = [i for i, name in devs if "debian" in name.lower()]
    pip = [i for i, name in devs if "debian" not in name.lower()]
    assert debian and pip, devs
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH)
    # pip's platform first in the preference order (as the fastest-first order may put it)
    env["GRAPHKIT_OPENCL_DEVICE"] = ",".join(pip + debian)
    p = _run(g, tmp_path / "out", tmp_path / "cache", env, "--backend", "opencl")
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    notices = [ln for ln in p.stderr.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1, p.stderr
    n = notices[0]
    assert f"using {debian[0]}" in n and "debian" in n.lower(), n
    assert "its compiler fails" in n and "pocl_types.h" in n, n  # the real compiler's error
    m = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert m["nodes"]["ratio"]["backend"] == "opencl"
    from conftest import read_exr

    got = read_exr(tmp_path / "out" / "ratio.exr")
    from skimage.data import astronaut

    a = astronaut().astype(np.float32)
    assert got.shape == a.shape and np.isfinite(got).all()
    # unset: whatever the loader's order, Debian's pocl runs it, with at most that one notice
    del env["GRAPHKIT_OPENCL_DEVICE"]
    p = _run(g, tmp_path / "out2", tmp_path / "cache2", env, "--backend", "opencl")
    assert p.returncode == 0, p.stderr
    assert len([ln for ln in p.stderr.splitlines() if ln.startswith("notice:")]) <= 1, p.stderr
    np.testing.assert_array_equal(read_exr(tmp_path / "out2" / "ratio.exr"), got)


def test_real_icd_only_broken_pip_pocl_falls_back_to_numpy(tmp_path):
    env = _env(tmp_path)
    (tmp_path / "vendors" / "debian-pocl.icd").unlink()  # pip's pocl alone, and it cannot build
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH)
    p = _run(g, tmp_path / "out", tmp_path / "cache", env, "--backend", "opencl")
    assert p.returncode == 0, p.stderr
    notices = [ln for ln in p.stderr.splitlines() if ln.startswith("notice:")]
    assert len(notices) == 1, p.stderr
    assert "no OpenCL device can run kernels here" in notices[0] and "using numpy" in notices[0]
    m = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert m["nodes"]["ratio"]["backend"] == "numpy"
    # pinned: exit 2 naming the node, the backend and the reason
    pinned = tmp_path / "pinned.yaml"
    pinned.write_text(GRAPH.replace("    params: {eps: 0.05}\n", "    params: {eps: 0.05}\n    backend: opencl\n"))
    p = _run(pinned, tmp_path / "out3", tmp_path / "cache3", env)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    assert "'ratio'" in p.stderr and "opencl" in p.stderr and "its compiler fails" in p.stderr


def test_no_platform_at_all(fresh_runtime, monkeypatch):
    """No ICD installed: clGetPlatformIDs fails (what pyopencl raises then); every backend is
    unavailable with the reason and what to install."""
    import pyopencl as cl

    from graphkit.registry import default_registry

    def none():
        raise cl.RuntimeError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")

    monkeypatch.setattr(cl, "get_platforms", none)
    with pytest.raises(fresh_runtime.Unavailable, match="no OpenCL platform found.*pocl-opencl-icd"):
        fresh_runtime.runtime()
    b = default_registry().backend_class("KMStack", "opencl")
    assert not b.available() and "no OpenCL platform found" in b.why_unavailable()
