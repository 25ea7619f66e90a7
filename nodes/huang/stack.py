"""KMStack — n Kubelka–Munk layers over a background, per pixel (Huang et al. 2013 §3.1 eqs. 3–4)."""
from __future__ import annotations

from typing import Literal

import numpy as np

from graphkit import BadInput, Field, Image, In, Node, Out, Spectrum

from nodes.common.parallel import run_bands

from . import km
from .layer import layer_thicknesses
from .library import KMLayerSpec, check_illuminant, layer_arrays, resolve_layers, skin_spectrum


def channel_max(t: np.ndarray, n: int) -> list[float]:
    """Per-channel maxima of an (H, W, n) map: row-wise maxima over (H, W·n) first (a reduction
    over the outer axis runs on whole rows; ``t[..., i].max()`` walks a strided view)."""
    h, w = t.shape[:2]
    if t.size == 0:
        return [0.0] * n
    return [float(v) for v in np.asarray(t).reshape(h, w * n).max(axis=0).reshape(w, n).max(axis=0)]


def pixel_stack(S, K, wl, thickness, illuminant="D65", lut_size=25, background_spectrum=None):
    """Per-pixel linear-RGB stack quantities for layers (bottom first) and a thickness map (mm).

    The spectral KM work (eqs. 1–4 per wavelength) is done on a grid of layer thicknesses
    (``lut_size`` nodes per layer from 0 to the map's maximum) and converted to RGB there; pixels
    interpolate multilinearly in thickness (exact where thicknesses are grid nodes, e.g. binary
    masks times a thickness).  Returns a dict of float32 (H, W, 3) arrays: ``R`` (over the
    spectral background, when given), else ``Rt``, ``Rb``, ``T`` and ``T2`` (RGB of the spectral
    T², used to put the stack over an RGB background); always ``T``.  ``Rb``, ``T``, ``T2`` are
    RGB filters: RGB(x)/RGB(1), so that zero thickness gives exactly 0, 1, 1.
    """
    n = S.shape[0]
    grids = km.thickness_grid(channel_max(thickness, n), lut_size)
    bg = None if background_spectrum is None else np.asarray(background_spectrum, np.float64)
    table = km.stack_rgb_table(S, K, wl, grids, illuminant, bg, full=False)
    names = ("R", "T") if bg is not None else ("Rt", "Rb", "T", "T2")
    return dict(zip(names, km.lookup(table, grids, thickness)))


def stack_over_rgb(S, K, wl, thickness, Rg, illuminant="D65", lut_size=25):
    """(R over the RGB background Rg, T) per pixel, float32 (H, W, 3) each: the four tables
    looked up, then Rt + T²·Rg/(1 − Rb·Rg) on bands of rows on all cores."""
    n = S.shape[0]
    h, w = thickness.shape[:2]
    grids = km.thickness_grid(channel_max(thickness, n), lut_size)
    table = km.stack_rgb_table(S, K, wl, grids, illuminant, None, full=False)
    R = np.empty((h, w, 3), np.float32)
    Rt, Rb, Tq, T2 = km.lookup(table, grids, thickness)

    def combine(r0, r1):
        g = Rg[r0:r1]
        den = np.multiply(Rb[r0:r1], g)
        np.subtract(np.float32(1), den, out=den)
        num = np.multiply(T2[r0:r1], g, out=R[r0:r1])
        np.divide(num, den, out=num)
        num += Rt[r0:r1]

    run_bands(combine, h, max(1, km.LOOKUP_BLOCK // max(w, 1)))
    return R, Tq


class KMStack(Node):
    """Cosmetic layers over skin → combined reflectance and transmittance, per pixel (Huang 2013 §3.1, eqs. 1–4).

    Layers (bottom first: e.g. foundation, blush, lipstick) come from the ``layers`` input
    (KMLayer / KMInvert nodes) or by name from the cosmetics library (``cosmetics``).  The
    cosmetic map ``thickness`` (H×W×n, mm; channel i = layer i) gives each layer's region and
    thickness.  Eqs. 3–4 are applied per wavelength for n layers (keeping reflectance from above
    and below), then spectral → XYZ (``illuminant``, CIE 1931 2°) → linear sRGB with
    colour-science.  The background is a spectral reflectance (``background_spectrum`` input or
    the ``background`` param — CIE TCS13 "human complexion" by default: fully spectral), or a
    linear-RGB reflectance image (``background`` input, e.g. a skin albedo), combined in RGB as
    Rt + T²·Rg/(1 − Rb·Rg) (an approximation: RGB of products ≠ products of RGB).
    Units: thickness mm, S and K mm⁻¹, wavelengths nm.
    """

    # 2: the thickness lookup puts each axis within km.SNAP of a node on it (was: only pixels
    #    with every axis there); values there move by ≤ ~2e-5
    version = "2"
    studio_view = "nodes.huang.studio_view:MakeupView"  # graphkit serve: layer sliders
    inputs = {
        "thickness": In(Image, "cosmetic map: H×W×n layer thicknesses in mm, bottom layer first",
                        same_size_as="background", finite=True, ge=0),
        "layers": In(KMLayerSpec, "layers, bottom first (else the 'cosmetics' param)", optional=True, variadic=True),
        "background": In(Image, "linear-RGB reflectance under the layers (e.g. skin albedo)", optional=True,
                         channels=3, finite=True, ge=0, le=1),
        "background_spectrum": In(Spectrum, "spectral reflectance under the layers", optional=True,
                                  finite=True, ge=0, le=1),
    }
    outputs = {"reflectance": Out(Image, "linear RGB reflectance of layers + background"),
               "transmittance": Out(Image, "linear RGB diffuse transmittance of the layers")}
    tolerance = {"rtol": 1e-4, "atol": 1e-5}
    # the per-pixel maths, as hooks a backend replaces (plugins/graphkit-opencl)
    hooks = ("pixel_stack", "stack_over_rgb")
    pixel_stack = staticmethod(pixel_stack)
    stack_over_rgb = staticmethod(stack_over_rgb)

    class Params(Node.Params):
        cosmetics: list[str] = Field(default_factory=list, description="library cosmetics, bottom layer first")
        illuminant: str = Field("D65", description="CIE illuminant for spectral → RGB (colour-science name)")
        background: Literal["skin_tcs13", "black", "white"] = Field(
            "skin_tcs13", description="spectral background when no background input is connected")
        lut_size: int = Field(25, ge=2, le=257, description="thickness grid nodes per layer (25: ΔE00 < 0.06 from the exact spectral result between nodes)")

    def compute(self, thickness: Image, layers: list | None = None, background: Image | None = None,
                background_spectrum: Spectrum | None = None):
        p = self.params
        check_illuminant(p.illuminant)
        specs = resolve_layers(layers, p.cosmetics)
        wl, S, K = layer_arrays(specs)
        if background is not None and background_spectrum is not None:
            raise BadInput("background_spectrum", "connect background or background_spectrum, not both")
        t = layer_thicknesses(thickness, len(specs))
        if background is not None:
            Rg = background.pixels
            R, T = self.stack_over_rgb(S, K, wl, t, Rg, p.illuminant, p.lut_size)
            return {"reflectance": Image(R), "transmittance": Image(T)}
        if background_spectrum is not None:
            bg = np.interp(wl, background_spectrum.wavelengths, background_spectrum.values)
        else:
            bg = {"skin_tcs13": lambda: skin_spectrum(wl), "black": lambda: np.zeros_like(wl),
                  "white": lambda: np.ones_like(wl)}[p.background]()
        q = self.pixel_stack(S, K, wl, t, p.illuminant, p.lut_size, bg)
        return {"reflectance": Image(q["R"]), "transmittance": Image(q["T"])}

    @classmethod
    def examples(cls):
        h, w = 24, 32
        yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
        t = np.stack([0.03 * (xx > 0.2), 0.05 * yy, 0.04 * (xx * yy > 0.3)], -1)
        bg = np.full((h, w, 3), [0.6, 0.4, 0.3])
        cos = ["foundation_light", "blush_rose", "lipstick_red"]
        return [({"cosmetics": cos}, {"thickness": Image(t)}),
                ({"cosmetics": cos, "illuminant": "A"}, {"thickness": Image(t), "background": Image(bg)})]
