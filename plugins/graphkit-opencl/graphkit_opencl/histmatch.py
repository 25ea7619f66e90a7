"""The ``opencl`` backend of ``LocalHistMatch`` (Jimenez et al. 2010 §4.1 eqs. 1–3, §4.2, §6).

The node's own ``compute`` runs unchanged; its two full-resolution passes of the fast path —
the per-cell moments (hook ``cell_moments``) and eq. (3) applied with the grid's scale and bias
resampled bilinearly (hook ``apply_scale_bias``) — run as the kernels of
``shaders/opencl/histmatch.cl``.  The statistics on the cell grid in between (centring, the
disc filter, scale = σ/σ_n) are the reference's own code.  The exact mode (FFT) and radii below
8 px (c = 1) are the reference's too: there the moments hook is not called.

The moment sums are accumulated in double: a device without cl_khr_fp64 makes the backend
unavailable (a preferred backend falls back to numpy with a notice).
"""
from __future__ import annotations

import numpy as np

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/histmatch.cl"


def cell_moments(h: np.ndarray, m: np.ndarray | None, c: int):
    """nodes.jimenez.histmatch._cell_moments on the device: (Σh·m/c², Σh²·m/c²) per c × c
    cell; the cells cut off by the last row / column by the reference's ``cell_means``."""
    import cv2

    from nodes.jimenez.histmatch import cell_means

    rt = runtime()
    H, W = h.shape
    gH, gW = -(-H // c), -(-W // c)
    qH, qW = H // c, W // c
    a1 = np.zeros((gH, gW), np.float32)
    a2 = np.zeros_like(a1)
    h = np.ascontiguousarray(h, np.float32)
    m = None if m is None else np.ascontiguousarray(m, np.float32)
    what = f"the cell moments of a {W}×{H} map"
    check_fits(rt, what, [h.nbytes, 0 if m is None else m.nbytes, 2 * a1.nbytes])
    if qH and qW:
        prg = rt.program(SHADER)
        with cannot_run(rt, what), Buffers(rt) as B:
            args = [B.input(h), B.input(m if m is not None else np.zeros(1, np.float32)),
                    B.output(a1), B.output(a2),
                    np.int32(W), np.int32(c), np.int32(gW), np.int32(qW), np.int32(m is not None)]
            ev = launch(rt, prg, "cell_moments", (qW, qH), args)
            B.read([ev])
    for ys, xs in ((slice(qH * c, H), slice(0, W)), (slice(0, qH * c), slice(qW * c, W))):
        hb = h[ys, xs]
        if hb.size == 0:
            continue
        x = hb if m is None else cv2.multiply(hb, m[ys, xs])
        r0 = qH if ys.start else 0
        c0 = qW if xs.start else 0
        e1, e2 = cell_means(x, c), cell_means(cv2.multiply(x, hb), c)
        a1[r0:r0 + e1.shape[0], c0:c0 + e1.shape[1]] = e1
        a2[r0:r0 + e2.shape[0], c0:c0 + e2.shape[1]] = e2
    return a1, a2


def apply_scale_bias(hn: np.ndarray, scale: np.ndarray, mu: np.ndarray, mu_n: np.ndarray, c: int = 1):
    """nodes.jimenez.histmatch.apply_scale_bias on the device: max(a·H_n + b, 0), a = scale,
    b = μ − a·μ_n given on the grid of c-pixel cells (bilinear) or per pixel (c = 1)."""
    from nodes.jimenez.histmatch import grid_resize

    rt = runtime()
    a = np.ascontiguousarray(scale, np.float32)
    b = np.ascontiguousarray(np.asarray(mu, np.float32) - a * np.asarray(mu_n, np.float32))
    hn = np.ascontiguousarray(hn, np.float32)
    H, W = hn.shape
    gH, gW = a.shape
    if c > 1 and (gH * c, gW * c) != (H, W):  # cells sticking out of the image: as the reference
        a, b = grid_resize(a, c, (H, W)), grid_resize(b, c, (H, W))
        c, gH, gW = 1, H, W
    out = np.empty((H, W), np.float32)
    what = f"eq. (3) on a {W}×{H} map"
    check_fits(rt, what, [hn.nbytes, a.nbytes, b.nbytes, out.nbytes])
    prg = rt.program(SHADER)
    with cannot_run(rt, what), Buffers(rt) as B:
        args = [B.input(hn), B.input(np.ascontiguousarray(a, np.float32)), B.input(np.ascontiguousarray(b, np.float32)),
                B.output(out), np.int32(H), np.int32(W), np.int32(c), np.int32(gH), np.int32(gW)]
        ev = launch(rt, prg, "apply_scale_bias", (W, H), args)
        B.read([ev])
    return out


class LocalHistMatchOpenCL(OpenCLBackend):
    """LocalHistMatch with the fast path's per-pixel passes in ``shaders/opencl/histmatch.cl``."""

    node = "LocalHistMatch"
    kernel_version = "1"
    shaders = (SHADER,)
    needs_fp64 = True
    #: the node's rtol/atol, and 0.5 % of values beyond them: ``scale`` = σ/σ_n where a disc
    #: holds only a few skin pixels (outside a mask, where σ² is a float32 difference of
    #: moments divided by a small mask mass) is round-off in the reference itself; on the
    #: astronaut's blush basis 0.25 % of the scale map (all ≥ 20 px outside the skin) differ by
    #: up to 0.43 while matched, bias and neutral_mean agree to 1.5e-8
    tolerance = {"rtol": 1e-4, "atol": 1e-5, "bad_fraction": 0.005}
    #: benchmarks/bench_opencl.py, 2048², pocl on 2 cores: numpy ÷ opencl 0.74–1.5 (r = 16, 128)
    cpu_note = "not faster than numpy's cv2 passes (benchmarks/bench_opencl.py: 0.7-1.5x at 2048²)"

    @classmethod
    def hooks(cls):
        return {"cell_moments": cell_moments, "apply_scale_bias": apply_scale_bias}
