"""The per-process OpenCL state: one context, one in-order queue, one program per kernel file.

Building a program costs tens to hundreds of milliseconds, so everything is made once per
process and shared by all threads (the engine runs nodes in threads):

* context, queue and programs are created under a lock, at most once per process id (a forked
  child — e.g. a Dask worker — gets its own, since OpenCL objects do not survive ``fork``);
* OpenCL API calls are thread-safe except setting the arguments of one ``cl.Kernel`` object,
  so callers make a fresh ``cl.Kernel`` per call (cheap) instead of sharing one.

Environment:

``GRAPHKIT_OPENCL_DEVICE``
    which device to use: ``P:D`` (platform and device index, as listed by
    :func:`list_devices`), a device type (``gpu``, ``cpu``, ``accelerator``), or a
    case-insensitive part of "platform name / device name" (e.g. ``pthread``, ``nvidia``).
    Unset: the first device of the first platform that has one.
``GRAPHKIT_OPENCL_DISABLE``
    set to a non-empty value other than ``0`` to make every OpenCL backend report itself
    unavailable (the engine then falls back to numpy, or refuses a graph that pins opencl).
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import Any

DEVICE_ENV = "GRAPHKIT_OPENCL_DEVICE"
DISABLE_ENV = "GRAPHKIT_OPENCL_DISABLE"
# Division and sqrt rounded like IEEE / numpy, so results match the numpy reference.
BUILD_OPTIONS = ["-cl-fp32-correctly-rounded-divide-sqrt"]


class Unavailable(RuntimeError):
    """OpenCL cannot be used here; the message says why."""


@dataclass
class Runtime:
    cl: Any  # the pyopencl module
    device: Any
    context: Any
    queue: Any
    programs: dict[str, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def host_memory(self) -> bool:
        """True for CPU devices: buffers can wrap host arrays without copying."""
        return bool(self.device.type & self.cl.device_type.CPU)

    def describe(self) -> str:
        return f"{self.device.platform.name.strip()} / {self.device.name.strip()}"

    def program(self, shader: str) -> Any:
        """The built program of ``shaders/<shader>`` (built once per process)."""
        with self.lock:
            prg = self.programs.get(shader)
            if prg is None:
                from graphkit.resources import shader_source

                try:
                    src = shader_source(shader)
                except FileNotFoundError as e:
                    raise Unavailable(str(e)) from None
                try:
                    prg = self.cl.Program(self.context, src).build(options=BUILD_OPTIONS)
                except self.cl.Error as e:
                    raise Unavailable(f"{shader} does not build on {self.describe()}: {e}") from None
                self.programs[shader] = prg
            return prg


_lock = threading.Lock()
_cache: dict[tuple[int, str], Runtime | Unavailable] = {}


def disabled() -> str | None:
    v = os.environ.get(DISABLE_ENV, "").strip()
    if v and v != "0":
        return f"disabled by {DISABLE_ENV}={v}"
    return None


def list_devices() -> list[tuple[str, Any]]:
    """[("P:D", device)] for every OpenCL device of every platform."""
    import pyopencl as cl

    out = []
    try:
        platforms = cl.get_platforms()
    except cl.Error as e:  # no ICD loader / no platform installed
        raise Unavailable(f"no OpenCL platform found ({e}); install an OpenCL driver, e.g. "
                          "`pip install pocl-binary-distribution` for the CPU") from None
    for pi, p in enumerate(platforms):
        try:
            devices = p.get_devices()
        except cl.Error:  # a platform without devices raises DEVICE_NOT_FOUND
            continue
        out.extend((f"{pi}:{di}", d) for di, d in enumerate(devices))
    return out


def select_device(spec: str) -> Any:
    import pyopencl as cl

    devices = list_devices()
    if not devices:
        raise Unavailable("no OpenCL device found; install an OpenCL driver, e.g. "
                          "`pip install pocl-binary-distribution` for the CPU")
    spec = spec.strip()
    if not spec:
        return devices[0][1]
    s = spec.lower()
    for idx, d in devices:
        if s == idx:
            return d
    types = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU, "accelerator": cl.device_type.ACCELERATOR}
    for idx, d in devices:
        if (s in types and d.type & types[s]) or s in f"{d.platform.name} / {d.name}".lower():
            return d
    listing = "; ".join(f"{idx} = {d.platform.name.strip()} / {d.name.strip()}" for idx, d in devices)
    raise Unavailable(f"{DEVICE_ENV}={spec!r} matches no OpenCL device (devices: {listing})")


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


def _make(spec: str) -> Runtime | Unavailable:
    try:
        import pyopencl as cl
    except ImportError as e:
        return Unavailable(f"pyopencl is not installed ({e}); `pip install pyopencl pocl-binary-distribution`")
    try:
        device = select_device(spec)
        context = cl.Context([device])
        queue = cl.CommandQueue(context, device)
    except Unavailable as e:
        return e
    except cl.Error as e:
        return Unavailable(f"OpenCL initialisation failed: {e}")
    return Runtime(cl, device, context, queue)
