"""The ``opencl`` backend of ``Relight`` (Loscos, Drettakis, Robert 2000 §4.4, §5).

The node's own ``compute`` runs unchanged (emittances, virtual lights and boxes, the
preprocess ``prepare``); its per-pixel modulation — hook ``relight_fast``: B = Σ_s resp_s·e_s
at each pixel's leaf times the pixel's base — is the kernel ``shaders/opencl/relight.cl``.
Inserting virtual lights or boxes (§4.5) re-solves the radiosity on the host: that path is the
reference's own.
"""
from __future__ import annotations

import numpy as np

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/relight.cl"


def relight_fast(prep: dict, e: np.ndarray) -> np.ndarray:
    """nodes.loscos.relight.relight_fast on the device: image = base × B at the pixels' leaves,
    B = Σ_s resp_s · e_s; other pixels keep the photograph."""
    rt = runtime()
    resp = np.ascontiguousarray(prep["resp"], np.float32)  # (3, L, S)
    _, L, S = resp.shape
    out = np.array(prep["photo"], np.float32, order="C")   # (H, W, 3)
    pix = np.flatnonzero(prep["mask"]).astype(np.int32)
    n = pix.size
    if n == 0:
        return out
    leaf = np.ascontiguousarray(prep["k"], np.int32)
    base = np.ascontiguousarray(prep["base"], np.float32)
    e32 = np.ascontiguousarray(np.asarray(e, np.float32).reshape(S, 3))
    what = f"relighting a {out.shape[1]}×{out.shape[0]} image"
    check_fits(rt, what, [out.nbytes, pix.nbytes, leaf.nbytes, base.nbytes, resp.nbytes])
    prg = rt.program(SHADER, (f"-DS={S}",))
    with cannot_run(rt, what), Buffers(rt) as B:
        args = [B.output(out), B.input(pix), B.input(leaf), B.input(base), B.input(resp), B.input(e32),
                np.int32(L), np.int32(n)]
        if not rt.host_memory:  # the photo must be on the device first: out is read-write
            rt.cl.enqueue_copy(rt.queue, args[0], out, is_blocking=True)
        ev = launch(rt, prg, "relight", n, args)
        B.read([ev])
    return out


class RelightOpenCL(OpenCLBackend):
    """Relight with its per-pixel modulation in ``shaders/opencl/relight.cl``."""

    node = "Relight"
    node_class = "nodes.loscos.relight:Relight"
    kernel_version = "1"
    shaders = (SHADER,)
    #: benchmarks/bench_opencl.py, Cornell at 12k leaves, 128×128 (15k drawn pixels), pocl on 2
    #: cores: numpy ~1 ms; the device's per-call cost (buffers, launch, waking its threads) is more
    cpu_note = "slower than numpy at this image size: ~1 ms of per-pixel work vs the device's per-call cost"

    @classmethod
    def hooks(cls):
        return {"relight_fast": relight_fast}
