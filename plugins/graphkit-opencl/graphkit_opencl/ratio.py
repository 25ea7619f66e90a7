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
    """a / max(b, eps) for float32 H×W×C ``a`` and H×W×(1 or C) ``b``, on the OpenCL device."""
    rt = runtime()
    cl = rt.cl
    a = np.ascontiguousarray(a, dtype=np.float32)
    b = np.ascontiguousarray(b, dtype=np.float32)
    out = np.empty_like(a)
    n = a.size
    if n == 0:
        return out
    limit = rt.device.max_mem_alloc_size
    if a.nbytes > limit:
        raise MemoryError(f"image of {a.nbytes / 1e6:.0f} MB exceeds the largest buffer of "
                          f"{rt.describe()} ({limit / 1e6:.0f} MB)")
    mf = cl.mem_flags
    ctx, queue = rt.context, rt.queue
    a_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
    b_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=b)
    o_buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    try:
        kernel = cl.Kernel(rt.program(SHADER), "ratio")  # per call: kernel args are not thread-safe
        kernel.set_args(a_buf, b_buf, o_buf, np.uint64(n), np.uint32(a.shape[2]),
                        np.uint32(b.shape[2]), np.float32(eps))
        cl.enqueue_nd_range_kernel(queue, kernel, (n,), None)
        cl.enqueue_copy(queue, out, o_buf, is_blocking=True)
    finally:
        for buf in (a_buf, b_buf, o_buf):
            buf.release()
    return out
