"""The per-process OpenCL state: one device, context, in-order queue and program cache.

Building a program costs tens of milliseconds (pocl's on-disk kernel cache) to seconds (a cold
LLVM compile), so everything is made once per process and device and shared by all threads and
all nodes of a run (the engine runs nodes in threads), and by every later run in the same
process (the studio's frames):

* the device is chosen once per process (and per ``GRAPHKIT_OPENCL_DEVICE`` value): the
  candidates in order of preference (:func:`candidates`) are **probed** — a small kernel is
  built and run on each — and the first that works is used.  A platform whose compiler fails
  (pip's ``pocl-binary-distribution`` on AMD Zen 5: ``unknown target CPU 'generic'``) is
  skipped with one notice line on stderr naming it and the reason;
* context, queue and programs are created under a lock, at most once per process id (a forked
  child — e.g. a Dask worker — gets its own, since OpenCL objects do not survive ``fork``);
* OpenCL API calls are thread-safe except setting the arguments of one ``cl.Kernel`` object,
  so callers make a fresh ``cl.Kernel`` per call (cheap) instead of sharing one.

Environment:

``GRAPHKIT_OPENCL_DEVICE``
    which device(s) to use, as a comma-separated list tried in order; each entry is ``P:D``
    (platform and device index, as listed by :func:`list_devices`), a device type (``gpu``,
    ``cpu``, ``accelerator``), or a case-insensitive part of "platform name platform version /
    device name" (e.g. ``pthread``, ``nvidia``, ``3.1+debian``).  Unset: every device, the
    fastest first (:func:`speed_rank`).
``GRAPHKIT_OPENCL_DISABLE``
    set to a non-empty value other than ``0`` to make every OpenCL backend report itself
    unavailable (the engine then falls back to numpy, or refuses a graph that pins opencl).
"""
from __future__ import annotations

import os
import sys
import threading
from dataclasses import dataclass, field
from typing import Any

DEVICE_ENV = "GRAPHKIT_OPENCL_DEVICE"
DISABLE_ENV = "GRAPHKIT_OPENCL_DISABLE"
# Division and sqrt rounded like IEEE / numpy, so results match the numpy reference.
BUILD_OPTIONS = ["-cl-fp32-correctly-rounded-divide-sqrt"]

#: built and run on every candidate device before it is used: a compiler that cannot build
#: this cannot build any of our kernels
PROBE_SOURCE = """
__kernel void graphkit_probe(__global float *x)
{
    const size_t i = get_global_id(0);
    x[i] = x[i] * 2.0f + 1.0f;
}
"""


class Unavailable(RuntimeError):
    """OpenCL cannot be used here; the message says why."""


def _short_version(platform) -> str:
    """'OpenCL 3.0 PoCL 3.1+debian' out of pocl's long version string (build flags cut off)."""
    v = " ".join(platform.version.split())
    return v.split(" Linux")[0].split(",")[0].strip()


def describe_device(device) -> str:
    """'platform name (version) / device name': tells two pocl builds apart."""
    p = device.platform
    return f"{p.name.strip()} ({_short_version(p)}) / {device.name.strip()}"


@dataclass
class Runtime:
    cl: Any  # the pyopencl module
    device: Any
    context: Any
    queue: Any
    index: str = ""  # "P:D" in list_devices()
    programs: dict[tuple, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def host_memory(self) -> bool:
        """True for CPU devices: buffers can wrap host arrays without copying."""
        return bool(self.device.type & self.cl.device_type.CPU)

    @property
    def is_cpu(self) -> bool:
        return bool(self.device.type & self.cl.device_type.CPU)

    @property
    def has_fp64(self) -> bool:
        """The device does double precision (cl_khr_fp64 / a non-zero double_fp_config)."""
        try:
            return bool(self.device.double_fp_config)
        except self.cl.Error:
            return "cl_khr_fp64" in self.device.extensions

    def describe(self) -> str:
        return describe_device(self.device)

    def program(self, shader: str, options: tuple[str, ...] = ()) -> Any:
        """The built program of ``shader`` (see :func:`kernel_source`) with extra build
        ``options`` (built once per process and device)."""
        key = (shader, tuple(options))
        with self.lock:
            prg = self.programs.get(key)
            if prg is None:
                try:
                    src = kernel_source(shader)
                except (FileNotFoundError, ModuleNotFoundError) as e:
                    raise Unavailable(str(e)) from None
                try:
                    prg = self.cl.Program(self.context, src).build(options=BUILD_OPTIONS + list(options))
                except self.cl.Error as e:
                    raise Unavailable(f"{shader} does not build on {self.describe()}: {build_error(e)}") from None
                self.programs[key] = prg
            return prg


def kernel_source(shader: str) -> str:
    """The OpenCL C of ``shader``: ``"package:file.cl"`` is a file shipped inside a (plugin's)
    package, found with importlib.resources; a plain path is one under graphkit's ``shaders/``
    (e.g. ``opencl/ratio.cl``)."""
    package, sep, name = shader.rpartition(":")
    if not sep:
        from graphkit.resources import shader_source

        return shader_source(shader)
    from importlib.resources import files

    path = files(package).joinpath(name)
    if not path.is_file():
        raise FileNotFoundError(f"kernel {name} not found in package {package}")
    return path.read_text()


_lock = threading.Lock()
_cache: dict[tuple[int, str], Runtime | Unavailable] = {}


def disabled() -> str | None:
    v = os.environ.get(DISABLE_ENV, "").strip()
    if v and v != "0":
        return f"disabled by {DISABLE_ENV}={v}"
    return None


def list_devices() -> list[tuple[str, Any]]:
    """[("P:D", device)] for every OpenCL device of every platform, in the ICD loader's order."""
    import pyopencl as cl

    out = []
    try:
        platforms = cl.get_platforms()
    except cl.Error as e:  # no ICD loader / no platform installed
        raise Unavailable(f"no OpenCL platform found ({e}); install an OpenCL driver, e.g. Debian's "
                          "pocl-opencl-icd or `pip install pocl-binary-distribution` for the CPU") from None
    for pi, p in enumerate(platforms):
        try:
            devices = p.get_devices()
        except cl.Error:  # a platform without devices raises DEVICE_NOT_FOUND
            continue
        out.extend((f"{pi}:{di}", d) for di, d in enumerate(devices))
    return out


def speed_rank(device) -> tuple:
    """Sort key, larger = expected faster: GPUs, then accelerators, then CPUs; within a kind,
    compute units × clock.  Ties keep the ICD loader's order."""
    import pyopencl as cl

    t = device.type
    kind = 2 if t & cl.device_type.GPU else 1 if t & cl.device_type.ACCELERATOR else 0
    try:
        work = int(device.max_compute_units) * int(device.max_clock_frequency or 1)
    except cl.Error:
        work = 0
    return (kind, work)


def candidates(spec: str, devices: list[tuple[str, Any]] | None = None) -> list[tuple[str, Any]]:
    """The devices to try, in order: those matching ``spec`` (a comma-separated list, see the
    module docstring; each entry's matches fastest first), or every device fastest first."""
    import pyopencl as cl

    devices = list_devices() if devices is None else devices
    if not devices:
        raise Unavailable("no OpenCL device found; install an OpenCL driver, e.g. Debian's "
                          "pocl-opencl-icd or `pip install pocl-binary-distribution` for the CPU")
    by_speed = sorted(devices, key=lambda e: speed_rank(e[1]), reverse=True)  # stable: loader order on ties
    entries = [s.strip().lower() for s in spec.split(",") if s.strip()]
    if not entries:
        return by_speed
    types = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU, "accelerator": cl.device_type.ACCELERATOR}
    out: list[tuple[str, Any]] = []
    for s in entries:
        for idx, d in by_speed:
            hit = (s == idx or (s in types and d.type & types[s])
                   or s in f"{d.platform.name} {_short_version(d.platform)} / {d.name}".lower())
            if hit and all(idx != i for i, _ in out):
                out.append((idx, d))
    if not out:
        listing = "; ".join(f"{idx} = {describe_device(d)}" for idx, d in devices)
        raise Unavailable(f"{DEVICE_ENV}={spec!r} matches no OpenCL device (devices: {listing})")
    return out


def select_device(spec: str) -> Any:
    """The first device of :func:`candidates` (not probed)."""
    return candidates(spec)[0][1]


def build_error(e: Exception) -> str:
    """The line of an OpenCL build failure that says what is wrong (the compiler's first
    ``error:`` line, else the first line)."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    for ln in lines:
        if "error" in ln.lower() and not ln.startswith("clBuildProgram failed"):
            return ln
    return lines[0] if lines else type(e).__name__


def probe_device(cl, device) -> tuple[Any, Any] | str:
    """(context, queue) when a probe kernel builds and runs correctly on ``device``, else why not."""
    import numpy as np

    try:
        ctx = cl.Context([device])
        queue = cl.CommandQueue(ctx, device)
        try:
            prg = cl.Program(ctx, PROBE_SOURCE).build(options=BUILD_OPTIONS)
        except cl.Error as e:
            return f"its compiler fails: {build_error(e)}"
        x = np.arange(8, dtype=np.float32)
        buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
        k = cl.Kernel(prg, "graphkit_probe")
        k.set_args(buf)
        cl.enqueue_nd_range_kernel(queue, k, (8,), None)
        got = np.empty_like(x)
        cl.enqueue_copy(queue, got, buf, is_blocking=True)
        buf.release()
        if not np.array_equal(got, x * 2 + 1):
            return f"the probe kernel computed wrong values {got.tolist()}"
        return ctx, queue
    except cl.Error as e:
        return f"OpenCL initialisation failed: {e}"


def notice(message: str) -> None:
    """One line for the user (stderr, like the engine's notices)."""
    print(f"notice: {message}", file=sys.stderr, flush=True)


def runtime() -> Runtime:
    """This process's OpenCL runtime; raises :class:`Unavailable` with the reason."""
    why = disabled()
    if why:
        raise Unavailable(why)
    key = (os.getpid(), os.environ.get(DEVICE_ENV, ""))
    with _lock:
        rt = _cache.get(key)
        if rt is None:
            rt = _cache[key] = _make(key[1])
    if isinstance(rt, Unavailable):
        raise Unavailable(str(rt))  # a fresh exception: the cached one is shared by threads
    return rt


def current() -> Runtime | None:
    """The runtime if one was made in this process for the current settings (no probing)."""
    rt = _cache.get((os.getpid(), os.environ.get(DEVICE_ENV, "")))
    return rt if isinstance(rt, Runtime) else None


def _make(spec: str) -> Runtime | Unavailable:
    try:
        import pyopencl as cl
    except ImportError as e:
        return Unavailable(f"pyopencl is not installed ({e}); `pip install pyopencl pocl-binary-distribution`")
    try:
        cands = candidates(spec)
    except Unavailable as e:
        return e
    except cl.Error as e:
        return Unavailable(f"OpenCL initialisation failed: {e}")
    failed = []
    for idx, device in cands:
        got = probe_device(cl, device)
        if isinstance(got, str):
            failed.append(f"{idx} {describe_device(device)}: {got}")
            continue
        rt = Runtime(cl, device, got[0], got[1], idx)
        if failed:  # one line, however many platforms were skipped
            notice(f"OpenCL: skipped {'; '.join(failed)}; using {idx} {rt.describe()}")
        return rt
    return Unavailable("no OpenCL device can run kernels here: " + "; ".join(failed))
