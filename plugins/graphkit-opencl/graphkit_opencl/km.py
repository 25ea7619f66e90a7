"""The ``opencl`` backend of ``KMStack`` (Huang et al. 2013 §3.1, eqs. 1–4) and the per-pixel
thickness-table lookup shared with CosmeticShade's backend.

The node's own ``compute`` runs unchanged (input checks, layers, background): only its
per-pixel hooks ``pixel_stack`` / ``stack_over_rgb`` are replaced by :func:`pixel_stack` /
:func:`stack_over_rgb` here.  The spectral tables are built on the host by the reference's own
``km.stack_rgb_table`` (memoised per material set); the kernel ``shaders/opencl/km_lookup.cl``
does the lookup — and, over an RGB background, the combination Rt + T²·Rg/(1 − Rb·Rg) — in one
pass over the pixels.
"""
from __future__ import annotations

import numpy as np

from .base import Buffers, OpenCLBackend, cannot_run, check_fits, launch
from .runtime import runtime

SHADER = "opencl/km_lookup.cl"


def _packed(table, grids) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tables on one grid packed per node (nodes × NT × 4: RGB + 0), and per axis the scale (cells per
    mm), last node and node-index stride.  Memoised on the reference's ``km.Tables``."""
    key = ("opencl",) + tuple(np.asarray(g, np.float64).tobytes() for g in grids)
    plans = getattr(table, "plans", None)
    if plans is not None and key in plans:
        return plans[key]
    tables = [np.asarray(t, np.float32) for t in (table if isinstance(table, (list, tuple)) else [table])]
    sizes = [len(g) for g in grids]
    nodes = tables[0].size // tables[0].shape[-1]
    packed = np.zeros((nodes, len(tables), 4), np.float32)  # per node: each table's RGB + 0 (float4)
    for i, t in enumerate(tables):
        packed[:, i, :3] = t.reshape(-1, 3)
    # the reference's own float32 scale (km._Plan): (N − 1) / (g[-1] − g[0]), 0 for one node
    scale = np.array([(N - 1) / (g[-1] - g[0]) if N > 1 else 0.0 for g, N in zip(grids, sizes)], np.float32)
    last = np.array([N - 1 for N in sizes], np.float32)
    stride = np.array([int(np.prod(sizes[i + 1:], dtype=np.int64)) for i in range(len(sizes))], np.int32)
    out = (packed, scale, last, stride)
    if plans is not None:
        plans[key] = out
    return out


def lookup_tables(table, grids, thickness: np.ndarray, rg: np.ndarray | None = None) -> list[np.ndarray]:
    """km.lookup on the OpenCL device: float32 (H, W, 3) per table, or with ``rg`` (an RGB
    background, tables Rt, Rb, T, T²) the pair [R over rg, T]."""
    h, w, n = thickness.shape
    if n == 0:  # no layers: every pixel is the vacuum entry (the reference's own lookup)
        from nodes.huang import km

        res = km.lookup(table if isinstance(table, (list, tuple)) else [table], grids, thickness)
        if rg is None:
            return res
        Rt, Rb, T, T2 = res
        return [Rt + T2 * rg / (1.0 - Rb * rg), T]
    rt = runtime()
    packed, scale, last, stride = _packed(table, grids)
    NT = packed.shape[1]
    P = h * w
    over = rg is not None
    outs = ([np.empty((h, w, 3), np.float32), np.empty((h, w, 3), np.float32)] if over
            else [np.empty((NT, h, w, 3), np.float32)])
    if P == 0:
        return outs if over else list(outs[0])
    t = np.ascontiguousarray(thickness, np.float32)
    what = f"a {w}×{h} KM lookup"
    check_fits(rt, what, [t.nbytes, packed.nbytes] + [o.nbytes for o in outs] + ([P * 12] if over else []))
    prg = rt.program(SHADER, (f"-DNL={n}", f"-DNT={NT}", f"-DOVER_RGB={int(over)}"))
    with cannot_run(rt, what), Buffers(rt) as B:
        args = [B.input(t), B.input(packed), B.input(scale), B.input(last), B.input(stride),
                B.input(np.ascontiguousarray(rg, np.float32) if over else np.zeros(1, np.float32)),
                B.output(outs[0]), B.output(outs[1]) if over else B.scratch(4), np.uint32(P)]
        if rt.is_cpu:  # on-node pixels in a first pass, the listed others in a second
            count = np.zeros(h, np.int32)
            lst, cnt = B.scratch(4 * P), B.output(count)
            ev = launch(rt, prg, "km_nodes", h, args + [np.int32(w), lst, cnt])
            B.read([ev])  # the rows' counts: the second pass covers the longest list only
            m = int(count.max())
            if m:
                ev = launch(rt, prg, "km_interp", (m, h), args + [np.int32(w), lst, cnt])
        else:
            ev = launch(rt, prg, "km_lookup", P, args)
        B.read([ev])
    return outs if over else list(outs[0])


def pixel_stack(S, K, wl, thickness, illuminant="D65", lut_size=25, background_spectrum=None):
    """nodes.huang.stack.pixel_stack with the per-pixel lookup on the OpenCL device."""
    from nodes.huang import km
    from nodes.huang.stack import channel_max

    n = S.shape[0]
    grids = km.thickness_grid(channel_max(thickness, n), lut_size)
    bg = None if background_spectrum is None else np.asarray(background_spectrum, np.float64)
    table = km.stack_rgb_table(S, K, wl, grids, illuminant, bg)
    names = ("R", "T") if bg is not None else ("Rt", "Rb", "T", "T2")
    return dict(zip(names, lookup_tables(table, grids, thickness)))


def stack_over_rgb(S, K, wl, thickness, Rg, illuminant="D65", lut_size=25):
    """nodes.huang.stack.stack_over_rgb on the OpenCL device: lookup and combination in one pass."""
    from nodes.huang import km
    from nodes.huang.stack import channel_max

    n = S.shape[0]
    grids = km.thickness_grid(channel_max(thickness, n), lut_size)
    table = km.stack_rgb_table(S, K, wl, grids, illuminant, None)
    R, T = lookup_tables(table, grids, thickness, Rg)
    return R, T


class KMStackOpenCL(OpenCLBackend):
    """KMStack with its per-pixel thickness-table lookup (and RGB-background combination) in
    ``shaders/opencl/km_lookup.cl``."""

    node = "KMStack"
    kernel_version = "1"
    shaders = (SHADER,)

    @classmethod
    def hooks(cls):
        return {"pixel_stack": pixel_stack, "stack_over_rgb": stack_over_rgb}
