"""What every OpenCL backend of this plugin shares: the availability probe, the version that
names the device, the CPU preference rule, buffers, and out-of-memory handling.

A backend here is a :class:`OpenCLBackend` subclass that sets

* ``node`` / ``name = "opencl"`` / ``kernel_version`` (bump it when outputs change; the engine's
  ``version`` — part of the cache key and of the run manifest — is ``kernel_version`` plus the
  device, e.g. ``"1 (Portable Computing Language (OpenCL 3.0 PoCL 3.1+debian) / pthread-…)"``:
  results of different devices are not mixed in the cache, and the manifest says which device
  computed each node);
* ``shaders``: the kernel files it builds, under graphkit's ``shaders/`` (``opencl/ratio.cl``)
  or inside a plugin's own package (``"my_plugin:gain.cl"``) (``available()`` builds them: a
  program that does not build makes the backend unavailable, with the compiler's error);
* ``needs_fp64``: True when a kernel uses ``double`` (a device without it is unavailable);
* ``cpu_note``: None when the backend is at least as fast as numpy on a CPU device (pocl),
  else the measured reason it is not: on a CPU device it then *declines preference*
  (``--backend opencl`` keeps numpy, with one notice) while a pin still runs it.

and a ``compute`` with the node's signature.  Inside it, :func:`cannot_run` turns the device's
memory limits and OpenCL allocation failures into :class:`graphkit.BackendCannotRun`: the engine
then falls back to numpy for a preferred backend and refuses (exit 2) a pinned one.
"""
from __future__ import annotations

import contextlib
from typing import Any, ClassVar

import numpy as np

from graphkit import Backend

from .runtime import Runtime, Unavailable, runtime

try:  # graphkit >= the version with the hook; older engines report a node failure instead
    from graphkit import BackendCannotRun
except ImportError:  # pragma: no cover
    class BackendCannotRun(RuntimeError):  # type: ignore[no-redef]
        def __init__(self, reason):
            self.reason = reason
            super().__init__(reason)

#: OpenCL error codes that mean "out of memory" for these inputs
_OOM = {"MEM_OBJECT_ALLOCATION_FAILURE", "OUT_OF_RESOURCES", "OUT_OF_HOST_MEMORY",
        "INVALID_BUFFER_SIZE"}


class _DeviceVersion(type):
    """Metaclass: ``cls.version`` = ``kernel_version (device)`` (see the module docstring)."""

    @property
    def version(cls) -> str:
        try:
            dev = runtime().describe()
        except Unavailable:
            dev = "no OpenCL device"
        return f"{cls.kernel_version} ({dev})"


class OpenCLBackend(Backend, metaclass=_DeviceVersion):
    name = "opencl"
    kernel_version: ClassVar[str] = "1"
    shaders: ClassVar[tuple[str, ...]] = ()
    needs_fp64: ClassVar[bool] = False
    cpu_note: ClassVar[str | None] = None

    @classmethod
    def hooks(cls) -> dict[str, Any]:
        """{name of a hook the node type declares (``Node.hooks``): its device version}."""
        return {}

    def compute(self, **inputs):
        """The node's compute (input checks, host maths) with its per-pixel hooks on the device."""
        return self.accelerated()(self.params, self.ctx).compute(**inputs)

    @classmethod
    def accelerated(cls) -> type:
        """The registry's node class of ``node`` with :meth:`hooks` swapped in (made once);
        TypeError for a hook the node type does not declare in ``Node.hooks``."""
        acc = cls.__dict__.get("_accelerated_cls")
        if acc is None:
            from graphkit.registry import default_registry

            node = default_registry().node_class(cls.node)
            attrs = {k: staticmethod(f) for k, f in cls.hooks().items()}
            undeclared = sorted(set(attrs) - set(node.hooks))
            if undeclared:
                raise TypeError(f"{cls.__name__}: node type {cls.node} declares no hook "
                                f"'{undeclared[0]}' (its hooks: {', '.join(node.hooks) or 'none'})")
            attrs["type_name"] = node.type_name
            acc = type(f"{node.__name__}OnOpenCL", (node,), attrs)
            cls._accelerated_cls = acc
        return acc

    @classmethod
    def available(cls) -> bool:
        """True when pyopencl imports, a device works and every kernel builds (never raises)."""
        return cls._probe() is None

    @classmethod
    def why_unavailable(cls) -> str:
        return cls._probe() or "available"

    @classmethod
    def declines_preference(cls) -> str | None:
        try:
            rt = runtime()
        except Unavailable:
            return None
        if cls.cpu_note and rt.is_cpu:
            return f"{cls.cpu_note} on the CPU device {rt.describe()}; pin `backend: opencl` to use it anyway"
        return None

    @classmethod
    def _probe(cls) -> str | None:
        try:
            rt = runtime()
            if cls.needs_fp64 and not rt.has_fp64:
                return (f"the device {rt.describe()} has no double precision (cl_khr_fp64), which the "
                        f"{cls.node} kernels need")
            for s in cls.shaders:
                rt.program(s)
        except Unavailable as e:
            return str(e)
        except Exception as e:  # noqa: BLE001 - a probe reports, it does not raise
            return f"{type(e).__name__}: {e}"
        return None


def device_limits(rt: Runtime) -> tuple[int, int]:
    """(largest buffer, global memory) of the device in bytes."""
    return int(rt.device.max_mem_alloc_size), int(rt.device.global_mem_size)


def check_fits(rt: Runtime, what: str, sizes: list[int]) -> None:
    """Raise BackendCannotRun when buffers of ``sizes`` bytes do not fit on the device."""
    largest, total = device_limits(rt)
    big, need = max(sizes, default=0), sum(sizes)
    if big > largest:
        raise BackendCannotRun(f"{what} needs a buffer of {big / 2**20:.0f} MiB; the largest the device "
                               f"{rt.describe()} allows is {largest / 2**20:.0f} MiB")
    if need > total:
        raise BackendCannotRun(f"{what} needs {need / 2**20:.0f} MiB of device memory; the device "
                               f"{rt.describe()} has {total / 2**20:.0f} MiB")


@contextlib.contextmanager
def cannot_run(rt: Runtime, what: str):
    """OpenCL out-of-memory errors inside the block → BackendCannotRun naming ``what``."""
    cl = rt.cl
    try:
        yield
    except cl.MemoryError as e:
        raise BackendCannotRun(f"the device {rt.describe()} ran out of memory for {what}: {e}") from None
    except cl.Error as e:
        code = getattr(getattr(e, "code", None), "name", None) or str(e)
        if any(c in str(code) for c in _OOM):
            raise BackendCannotRun(f"the device {rt.describe()} ran out of memory for {what}: {e}") from None
        raise


class Buffers:
    """Device buffers for one kernel launch, released on exit.

    On a CPU device (pocl) buffers wrap the numpy arrays (``USE_HOST_PTR``: no copies) and
    outputs are made visible by mapping; on other devices inputs are copied in and outputs
    copied back by :meth:`read`.
    """

    def __init__(self, rt: Runtime):
        self.rt = rt
        self.bufs: list[Any] = []
        self.outs: list[tuple[Any, np.ndarray]] = []
        self.keep: list[np.ndarray] = []  # host memory wrapped by buffers: must outlive them

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        for b in self.bufs:
            b.release()
        self.bufs.clear()
        self.keep.clear()

    def input(self, a: np.ndarray):
        cl = self.rt.cl
        mf = cl.mem_flags
        a = np.ascontiguousarray(a)
        if a.nbytes == 0:
            a = np.zeros(1, a.dtype)
        host = mf.USE_HOST_PTR if self.rt.host_memory else mf.COPY_HOST_PTR
        b = cl.Buffer(self.rt.context, mf.READ_ONLY | host, hostbuf=a)
        self.bufs.append(b)
        self.keep.append(a)
        return b

    def output(self, a: np.ndarray):
        """A buffer whose contents end in ``a`` (C-contiguous) after :meth:`read`."""
        cl = self.rt.cl
        mf = cl.mem_flags
        assert a.flags.c_contiguous
        if self.rt.host_memory:
            b = cl.Buffer(self.rt.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=a)
        else:
            b = cl.Buffer(self.rt.context, mf.READ_WRITE, max(a.nbytes, 1))
        self.bufs.append(b)
        self.outs.append((b, a))
        return b

    def scratch(self, nbytes: int):
        cl = self.rt.cl
        b = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE, max(int(nbytes), 4))
        self.bufs.append(b)
        return b

    def read(self, wait_for=None) -> None:
        """Wait for the queue and make every output visible in its numpy array."""
        cl = self.rt.cl
        q = self.rt.queue
        for b, a in self.outs:
            if a.nbytes == 0:
                continue
            if self.rt.host_memory:
                mapped, _ = cl.enqueue_map_buffer(q, b, cl.map_flags.READ, 0, a.shape, a.dtype,
                                                  wait_for=wait_for, is_blocking=True)
                mapped.base.release(q).wait()
            else:
                cl.enqueue_copy(q, a, b, wait_for=wait_for, is_blocking=True)


def launch(rt: Runtime, program, kernel: str, size, args, local=None, wait_for=None):
    """Enqueue ``kernel`` of ``program`` over ``size`` work items (a fresh cl.Kernel: setting the
    arguments of a shared one is not thread-safe)."""
    cl = rt.cl
    k = cl.Kernel(program, kernel)
    k.set_args(*args)
    size = (size,) if isinstance(size, int) else tuple(size)
    return cl.enqueue_nd_range_kernel(rt.queue, k, size, local, wait_for=wait_for)
