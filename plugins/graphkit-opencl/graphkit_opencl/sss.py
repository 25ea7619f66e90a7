"""The ``opencl`` backends of ``SkinShade`` (Jimenez et al. 2010 §6) and ``CosmeticShade``
(Huang et al. 2013 §3): their shared screen-space subsurface scattering on the device.

Both nodes call the one SSS of ``nodes/common/sss.py`` through their hook ``sss_blur``; here it
is the reference's own ``sss_blur`` (validation, pixel steps from depth, the d'Eon profile
loop, the mask) with its one-axis Gaussian blur replaced by the kernel
``shaders/opencl/sss.cl``.  CosmeticShade's per-pixel KM lookup runs on the device as well
(the KMStack kernel, :mod:`graphkit_opencl.km`).

Where σ varies per pixel (a depth map or a per-pixel footprint) the kernel is the exact gather —
each pixel's own Gaussian — while the reference interpolates between uniform blurs at σ levels
a factor 2 apart (within ~1 % of a sharp step's height from the gather, much less on smooth
light such as the nodes' examples): hence the looser tolerance below.
"""
from __future__ import annotations

import numpy as np

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/sss.cl"
#: pixels per work item along a row (see sss.cl): blocks of 16 on CPUs (vectorised loops),
#: one on GPUs (neighbouring work items read neighbouring pixels)
V_CPU, V_GPU = 16, 1


def axis_blur(planes: list[np.ndarray], sigma, axis: int, valid: np.ndarray | None) -> list[np.ndarray]:
    """The one-axis blur of nodes.common.sss.sss_blur (the gather _blur_axis) on the device:
    float32 (H, W) planes blurred along ``axis`` with σ px (a float, or the reference's per-pixel plan whose ``sigma`` is the map)."""
    from nodes.common.sss import TRUNCATE, gaussian_kernel

    rt = runtime()
    H, W = planes[0].shape
    V = V_CPU if rt.is_cpu else V_GPU
    if isinstance(sigma, (int, float)):
        per_pixel, sd, taps = 0, 0.0, gaussian_kernel(float(sigma))
        R = taps.size // 2
        inv = np.zeros(1, np.float32)
        if R == 0 and valid is None:
            return [np.array(p, np.float32) for p in planes]
    else:  # the reference's plan: σ = scale · sigma per pixel
        per_pixel, sd, taps = 1, float(sigma.scale), np.zeros(1, np.float32)
        inv = np.ascontiguousarray(sigma.sigma, np.float32)
        R = int(TRUNCATE * sd * float(inv.max()) + 0.5) if inv.size else 0
    pad = [(0, 0), (0, 0)]
    pad[axis] = (R, R)
    what = f"the subsurface scattering of a {W}×{H} image"
    check_fits(rt, what, [4 * (H + 2 * R) * (W + 2 * R), 4 * H * W, inv.nbytes])
    prg = rt.program(SHADER, (f"-DV={V}", f"-DAXIS={axis}", f"-DPER_PIXEL={per_pixel}",
                              f"-DHAS_VALID={int(valid is not None)}"))

    def padded(a):  # mirrored borders along the axis (also wider than the image), V spare floats
        p = np.pad(np.asarray(a, np.float32), pad, mode="symmetric").ravel()
        return np.concatenate([p, np.zeros(V, np.float32)])

    v = padded(valid) if valid is not None else np.zeros(1, np.float32)
    dst = [np.empty((H, W), np.float32) for _ in planes]
    with cannot_run(rt, what), Buffers(rt) as B:
        vb, ib, tb = B.input(v), B.input(inv), B.input(np.ascontiguousarray(taps, np.float32))
        events = []
        for p, d in zip(planes, dst):
            args = [B.input(padded(p)), B.output(d), vb, ib, tb, np.int32(R), np.float32(sd),
                    np.int32(H), np.int32(W)]
            events.append(launch(rt, prg, "sss_axis", (-(-W // V), H), args))
        B.read(events)
    return dst


def sss_blur(irradiance, mm_per_pixel, depth=None, profile=None, mask=None):
    """nodes.common.sss.sss_blur with its one-axis blurs on the OpenCL device."""
    from nodes.common import sss

    return sss.sss_blur(irradiance, mm_per_pixel, depth, sss.SKIN_PROFILE if profile is None else profile,
                        mask, axis_blur=axis_blur)


#: per-pixel σ: the exact gather vs the reference's σ levels (see the module docstring); at a
#: sharp edge a few pixels differ by more (the makeup graphs on the astronaut: ≤ 7e-4, under
#: 0.01 % of the values; the reference's stated bound is 1.5 % of a step's height)
SSS_TOLERANCE = {"rtol": 1e-3, "atol": 1e-4, "bad_fraction": 1e-3}
#: benchmarks/bench_opencl.py, 1280×720, pocl on 2 cores: cv2.filter2D's separable passes win
SSS_CPU_NOTE = "slower than numpy's cv2.filter2D blur (benchmarks/bench_opencl.py)"


class SkinShadeOpenCL(OpenCLBackend):
    """SkinShade with its subsurface scattering in ``shaders/opencl/sss.cl``."""

    node = "SkinShade"
    kernel_version = "1"
    shaders = (SHADER,)
    tolerance = SSS_TOLERANCE
    cpu_note = SSS_CPU_NOTE

    @classmethod
    def hooks(cls):
        return {"sss_blur": sss_blur}


class CosmeticShadeOpenCL(OpenCLBackend):
    """CosmeticShade with its KM lookup (``km_lookup.cl``) and subsurface scattering
    (``sss.cl``) on the device."""

    node = "CosmeticShade"
    kernel_version = "1"
    shaders = (SHADER, "opencl/km_lookup.cl")
    tolerance = SSS_TOLERANCE
    cpu_note = SSS_CPU_NOTE

    @classmethod
    def hooks(cls):
        from .km import pixel_stack

        return {"sss_blur": sss_blur, "pixel_stack": pixel_stack}
