"""The ``opencl`` backend of ``RatioImage`` (Paris, Sillion, Quan 2003, §3): a / max(b, eps).

Kernel: ``shaders/opencl/ratio.cl``.  Inputs are checked by the reference's own
``check_ratio_inputs``, so both backends refuse the same inputs with the same message.
"""
from __future__ import annotations

import numpy as np

from graphkit import Image

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/ratio.cl"


class RatioImageOpenCL(OpenCLBackend):
    """RatioImage on an OpenCL device (any: pocl runs it on the CPU)."""

    node = "RatioImage"
    kernel_version = "1"  # bump when the output for the same inputs changes
    shaders = (SHADER,)

    def compute(self, a: Image, b: Image):
        from nodes.paris.ratio import check_ratio_inputs

        check_ratio_inputs(a, b)
        return Image(ratio_opencl(a.pixels, b.pixels, self.params.eps), a.colorspace)


def ratio_opencl(a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """a / max(b, eps) for float32 H×W×C ``a`` and H×W×(1 or C) ``b``, on the OpenCL device.

    On a CPU device (pocl) the buffers wrap the numpy arrays (``USE_HOST_PTR``: no copies);
    elsewhere the inputs are copied to the device and the result back (:class:`Buffers`).
    """
    rt = runtime()
    a = np.ascontiguousarray(a, dtype=np.float32)
    b = np.ascontiguousarray(b, dtype=np.float32)
    out = np.empty_like(a)
    if a.size == 0:
        return out
    what = f"the ratio of a {a.shape[1]}×{a.shape[0]} image"
    check_fits(rt, what, [a.nbytes, b.nbytes, out.nbytes])
    program = rt.program(SHADER)
    with cannot_run(rt, what), Buffers(rt) as B:
        bufs = [B.input(a), B.input(b), B.output(out)]
        if b.shape[2] == a.shape[2]:
            ev = launch(rt, program, "ratio", a.size, bufs + [np.uint64(a.size), np.float32(eps)])
        else:
            n = a.shape[0] * a.shape[1]
            ev = launch(rt, program, "ratio_broadcast", n,
                        bufs + [np.uint64(n), np.uint32(a.shape[2]), np.float32(eps)])
        B.read([ev])
    return out
