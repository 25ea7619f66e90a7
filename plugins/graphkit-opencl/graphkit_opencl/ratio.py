"""The ``opencl`` backend of ``RatioImage`` (Paris, Sillion, Quan 2003, §3): a / max(b, eps).

Kernel: ``shaders/opencl/ratio.cl``.  Inputs are checked by the reference's own
``check_ratio_inputs``, so both backends refuse the same inputs with the same message.
"""
from __future__ import annotations

import numpy as np

from graphkit import Backend, Image

from .runtime import Unavailable, runtime

SHADER = "opencl/ratio.cl"


class RatioImageOpenCL(Backend):
    """RatioImage on an OpenCL device (any: pocl runs it on the CPU)."""

    node = "RatioImage"
    name = "opencl"
    version = "1"  # bump when the output for the same inputs changes

    @classmethod
    def available(cls) -> bool:
        """True when pyopencl imports, a device is found and the kernel builds (never raises)."""
        return _probe() is None

    @classmethod
    def why_unavailable(cls) -> str:
        return _probe() or "available"

    def compute(self, a: Image, b: Image):
        from nodes.paris.ratio import check_ratio_inputs

        check_ratio_inputs(a, b)
        return Image(ratio_opencl(a.pixels, b.pixels, self.params.eps), a.colorspace)


def _probe() -> str | None:
    """None when the backend can run here, else why not (cheap after the first call)."""
    try:
        runtime().program(SHADER)
    except Unavailable as e:
        return str(e)
    except Exception as e:  # noqa: BLE001 - a probe reports, it does not raise
        return f"{type(e).__name__}: {e}"
    return None


def ratio_opencl(a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """a / max(b, eps) for float32 H×W×C ``a`` and H×W×(1 or C) ``b``, on the OpenCL device.

    On a CPU device (pocl) the buffers wrap the numpy arrays (``USE_HOST_PTR``: no copies);
    elsewhere the inputs are copied to the device and the result back.
    """
    rt = runtime()
    cl = rt.cl
    a = np.ascontiguousarray(a, dtype=np.float32)
    b = np.ascontiguousarray(b, dtype=np.float32)
    out = np.empty_like(a)
    if a.size == 0:
        return out
    limit = rt.device.max_mem_alloc_size
    if a.nbytes > limit:
        raise MemoryError(f"an image of {a.nbytes / 1e6:.0f} MB exceeds the largest buffer of "
                          f"{rt.describe()} ({limit / 1e6:.0f} MB)")
    mf = cl.mem_flags
    ctx, queue = rt.context, rt.queue
    host = mf.USE_HOST_PTR if rt.host_memory else mf.COPY_HOST_PTR
    bufs = [cl.Buffer(ctx, mf.READ_ONLY | host, hostbuf=a),
            cl.Buffer(ctx, mf.READ_ONLY | host, hostbuf=b)]
    try:
        if rt.host_memory:
            bufs.append(cl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out))
        else:
            bufs.append(cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes))
        program = rt.program(SHADER)
        # a Kernel object per call: setting the arguments of a shared one is not thread-safe
        if b.shape[2] == a.shape[2]:
            kernel = cl.Kernel(program, "ratio")
            kernel.set_args(*bufs, np.uint64(a.size), np.float32(eps))
            n = a.size
        else:
            kernel = cl.Kernel(program, "ratio_broadcast")
            n = a.shape[0] * a.shape[1]
            kernel.set_args(*bufs, np.uint64(n), np.uint32(a.shape[2]), np.float32(eps))
        done = cl.enqueue_nd_range_kernel(queue, kernel, (n,), None)
        if rt.host_memory:
            # mapping makes the results visible in ``out`` (the buffer's host memory)
            mapped, _ = cl.enqueue_map_buffer(queue, bufs[2], cl.map_flags.READ, 0, out.shape, out.dtype,
                                              wait_for=[done], is_blocking=True)
            mapped.base.release(queue).wait()
        else:
            cl.enqueue_copy(queue, out, bufs[2], wait_for=[done], is_blocking=True)
    finally:
        for buf in bufs:
            buf.release()
    return out
