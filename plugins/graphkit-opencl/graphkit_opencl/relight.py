"""The ``opencl`` backend of ``Relight`` (Loscos, Drettakis, Robert 2000 §4.4, §5).

The node's own ``compute`` runs unchanged (emittances, virtual lights and boxes, the
preprocess ``prepare``); its per-pixel maths — hook ``modulate_pixels``: base × Σ_s R_s·e_s + Σ_s G_s·e_s per drawn
pixel (nodes.loscos.display) — is the kernel ``shaders/opencl/relight.cl``.
Inserting virtual lights or boxes (§4.5) re-solves the radiosity on the host: that path is the
reference's own.
"""
from __future__ import annotations

import numpy as np

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/relight.cl"


def modulate_pixels(px, e: np.ndarray) -> np.ndarray:
    """nodes.loscos.display.modulate_pixels on the device: per drawn pixel
    base × Σ_s R_s·e_s + Σ_s G_s·e_s; other pixels keep the photograph."""
    rt = runtime()
    R = np.ascontiguousarray(px.R, np.float32)  # (S, n, 3)
    G = np.ascontiguousarray(px.G, np.float32)
    S, n, _ = R.shape
    out = np.array(px.photo, np.float32, order="C")   # (H, W, 3)
    if n == 0:
        return out
    pix = np.ascontiguousarray(px.index, np.int32)
    base = np.ascontiguousarray(px.base, np.float32)
    e32 = np.ascontiguousarray(np.asarray(e, np.float32).reshape(S, 3))
    what = f"relighting a {out.shape[1]}×{out.shape[0]} image"
    check_fits(rt, what, [out.nbytes, pix.nbytes, base.nbytes, R.nbytes, G.nbytes])
    prg = rt.program(SHADER, (f"-DS={S}",))
    with cannot_run(rt, what), Buffers(rt) as B:
        args = [B.output(out), B.input(pix), B.input(base), B.input(R), B.input(G), B.input(e32),
                np.int32(n)]
        if not rt.host_memory:  # the photo must be on the device first: out is read-write
            rt.cl.enqueue_copy(rt.queue, args[0], out, is_blocking=True)
        ev = launch(rt, prg, "relight", n, args)
        B.read([ev])
    return out


class RelightOpenCL(OpenCLBackend):
    """Relight with its per-pixel modulation in ``shaders/opencl/relight.cl``."""

    node = "Relight"
    kernel_version = "2"
    shaders = (SHADER,)
    #: benchmarks/bench_opencl.py, Cornell at 18k leaves, 128×128 (15k drawn pixels), pocl on 2
    #: cores: numpy 0.8 / 0.7 ms, opencl 0.6 / 0.6 ms (median / best): preferred on a CPU too
    cpu_note = None

    @classmethod
    def hooks(cls):
        return {"modulate_pixels": modulate_pixels}
