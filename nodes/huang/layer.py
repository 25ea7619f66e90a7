"""KMLayer, KMInvert and CosmeticMap (Huang et al. 2013 §3.1 eqs. 1–2, §4 eqs. 6–7)."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Field, Image, In, InputFile, Mask, Node, Out, Spectrum

from nodes.common.checks import inputs_or_param, same_wavelengths

from . import km
from .library import KMLayerSpec, check_illuminant, check_wavelengths, get_cosmetic, layer_arrays


def layer_thicknesses(img: Image, layers: int, port: str = "thickness") -> np.ndarray:
    """The cosmetic map's float32 H×W×n pixels (mm), one channel per layer (else BadInput; the
    port declares the rest: finite, ≥ 0, its size)."""
    t = img.pixels
    if t.shape[2] != layers:
        raise BadInput(port, f"thickness map has {t.shape[2]} channels but there are {layers} layers "
                       "(one channel per layer, bottom layer first)")
    return t


class KMLayer(Node):
    """One Kubelka–Munk cosmetic layer → R0 and T (Huang 2013 §3.1, eqs. 1–2).

    S and K spectra (mm⁻¹ at wavelengths in nm) come from the ``S``/``K`` inputs or from the
    library cosmetic named by ``cosmetic``.  Outputs the layer's reflectance over black R0 and
    its diffuse transmittance T at ``thickness_mm`` (mm) as spectra; their linear-sRGB values
    (spectral → XYZ under ``illuminant`` → linear sRGB via colour-science) per pixel of the
    optional ``thickness`` map (one channel, mm), else as a 1×1 image; and the ``layer``
    description that KMStack / CosmeticShade take.  Exact at K = 0, S → 0, X → 0 and X → ∞.
    """

    version = "2"
    inputs = {
        "S": In(Spectrum, "scattering coefficient, mm⁻¹ per wavelength (nm)", optional=True, finite=True, ge=0),
        "K": In(Spectrum, "absorption coefficient, mm⁻¹ per wavelength (nm)", optional=True, finite=True, ge=0),
        "thickness": In(Image, "optional thickness map, mm", optional=True, channels=1, finite=True, ge=0),
    }
    outputs = {
        "R0": Out(Spectrum, "reflectance of the layer over black (eq. 1) at thickness_mm"),
        "T": Out(Spectrum, "diffuse transmittance of the layer (eq. 2) at thickness_mm"),
        "R0_rgb": Out(Image, "linear sRGB of R0 per pixel of the thickness map (1×1 without one)"),
        "T_rgb": Out(Image, "linear sRGB of T per pixel of the thickness map (1×1 without one)"),
        "layer": Out(KMLayerSpec, "the layer for KMStack / CosmeticShade"),
    }
    tolerance = {"rtol": 1e-5, "atol": 1e-6}

    class Params(Node.Params):
        cosmetic: str = Field("", description="library cosmetic name (used when S and K are not connected)")
        name: str = Field("", description="layer name (default: the cosmetic name)")
        thickness_mm: float = Field(0.03, ge=0, description="layer thickness X, mm")
        illuminant: str = Field("D65", description="CIE illuminant for spectral → RGB (colour-science name)")
        m: float = Field(0.3, gt=0, description="Beckmann RMS slope of the layer surface (§3.3), when not from the library")
        rho_s: float = Field(0.1, ge=0, description="specular intensity (§3.3), when not from the library")
        f0: float = Field(0.028, ge=0, le=1, description="Fresnel reflectance at normal incidence")

    def compute(self, S: Spectrum | None = None, K: Spectrum | None = None, thickness: Image | None = None):
        p = self.params
        check_illuminant(p.illuminant)
        if inputs_or_param({"S": S, "K": K}, "cosmetic", p.cosmetic, "name a library cosmetic"):
            same_wavelengths({"S": S, "K": K})
            spec = KMLayerSpec(name=p.name or "layer", wavelengths=S.wavelengths.tolist(), S=S.values.tolist(),
                               K=K.values.tolist(), thickness_mm=p.thickness_mm, m=p.m, rho_s=p.rho_s, f0=p.f0)
            wl, Sa, Ka = layer_arrays([spec], "S")
        else:
            lib = get_cosmetic(p.cosmetic, "cosmetic")
            spec = lib.model_copy(update={"thickness_mm": p.thickness_mm, "name": p.name or lib.name})
            wl, Sa, Ka = layer_arrays([spec], "cosmetic")
        R0, T = km.layer_R0_T(Sa[0], Ka[0], p.thickness_mm)
        tmap = np.full((1, 1, 1), p.thickness_mm) if thickness is None else thickness.pixels
        grid = km.thickness_grid([float(tmap.max())], 65)
        R0g, Tg = km.layer_R0_T(Sa[0], Ka[0], grid[0][:, None])
        W = km.rgb_weights(wl, p.illuminant)
        r_px, t_px = km.lookup([R0g @ W, Tg @ W], grid, tmap)
        return {"R0": Spectrum(wl, R0, "reflectance"), "T": Spectrum(wl, T, "transmittance"),
                "R0_rgb": Image(r_px), "T_rgb": Image(t_px), "layer": spec}

    @classmethod
    def examples(cls):
        t = np.linspace(0, 0.2, 48 * 32).reshape(32, 48, 1)
        return [({"cosmetic": "lipstick_red", "thickness_mm": 0.05}, {}),
                ({"cosmetic": "foundation_light"}, {"thickness": Image(t)})]


def read_invert_csv(path: str, port: str = "path") -> tuple[np.ndarray, ...]:
    """Read a CSV with a header naming the columns wavelength, R, Rg, Rinf (any order)."""
    import csv

    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith("#")]
    except OSError as e:
        raise BadInput(port, f"cannot read {path}: {e.strerror}") from None
    if len(rows) < 3:
        raise BadInput(port, f"{path}: need a header and at least two rows")
    head = [h.strip().lower() for h in rows[0]]
    alias = {"wavelength": ("wavelength", "wavelength_nm", "nm", "lambda"), "r": ("r",), "rg": ("rg", "r_g"),
             "rinf": ("rinf", "r_inf", "r∞", "r_infinity")}
    idx = {}
    for key, names in alias.items():
        hit = [i for i, h in enumerate(head) if h in names]
        if not hit:
            raise BadInput(port, f"{path}: no column '{key}' in the header {rows[0]} (need wavelength, R, Rg, Rinf)")
        idx[key] = hit[0]
    try:
        data = np.array([[float(r[idx[k]]) for k in ("wavelength", "r", "rg", "rinf")] for r in rows[1:]])
    except (ValueError, IndexError) as e:
        raise BadInput(port, f"{path}: not a number in the data rows ({e})") from None
    return data[:, 0], data[:, 1], data[:, 2], data[:, 3]


class KMInvert(Node):
    """Measured reflectances → S and K per wavelength (Huang 2013 §4, eqs. 6–7).

    Reads a CSV (``path``) with columns wavelength (nm), R (a layer of thickness
    ``thickness_mm`` (mm) over a background), Rg (the background) and Rinf (an opaque layer), or
    takes the same as the ``R``, ``Rg``, ``Rinf`` Spectrum inputs.  Outputs S and K in mm⁻¹ and
    a ``layer`` description.  R must lie strictly between Rg and R∞ (over black: R < R∞).
    """

    version = "1"
    inputs = {"R": In(Spectrum, "thin layer over the background", optional=True, finite=True, ge=0, le=1),
              "Rg": In(Spectrum, "background", optional=True, finite=True, ge=0, le=1),
              "Rinf": In(Spectrum, "opaque layer", optional=True, finite=True, gt=0, le=1)}
    outputs = {"S": Out(Spectrum, "scattering coefficient, mm⁻¹"), "K": Out(Spectrum, "absorption coefficient, mm⁻¹"),
               "layer": Out(KMLayerSpec, "the cosmetic as a layer")}

    class Params(Node.Params):
        path: InputFile = Field("", description="CSV with columns wavelength (nm), R, Rg, Rinf; empty when the inputs are connected")
        thickness_mm: float = Field(0.15, gt=0, description="sample thickness D of the thin layer, mm (Huang's shallow container: 0.15)")
        name: str = Field("cosmetic", description="name of the resulting layer")
        layer_thickness_mm: float = Field(0.03, ge=0, description="default thickness of the resulting layer, mm")
        m: float = Field(0.3, gt=0, description="Beckmann RMS slope for the layer (§3.3)")
        rho_s: float = Field(0.1, ge=0, description="specular intensity for the layer (§3.3)")
        f0: float = Field(0.028, ge=0, le=1, description="Fresnel reflectance at normal incidence")

    def compute(self, R: Spectrum | None = None, Rg: Spectrum | None = None, Rinf: Spectrum | None = None):
        p = self.params
        connected = inputs_or_param({"R": R, "Rg": Rg, "Rinf": Rinf}, "path", p.path, "give a CSV path")
        if connected:
            same_wavelengths({"R": R, "Rg": Rg, "Rinf": Rinf})
            wl, r, rg, ri = R.wavelengths, R.values, Rg.values, Rinf.values
        else:
            wl, r, rg, ri = read_invert_csv(self.resolve_file("path", p.path, self.ctx.base_dir))
        check_wavelengths(wl, "R" if connected else "path")
        bad = km.check_invert_inputs(r, rg, ri)
        if bad:
            port, msg = bad if connected else ("path", f"column {bad[0]}: {bad[1]}")
            raise BadInput(port, msg)
        S, K = km.invert(r, rg, ri, p.thickness_mm)
        spec = KMLayerSpec(name=p.name, wavelengths=wl.tolist(), S=S.tolist(), K=K.tolist(),
                           thickness_mm=p.layer_thickness_mm, m=p.m, rho_s=p.rho_s, f0=p.f0)
        return {"S": Spectrum(wl, S, "1/mm"), "K": Spectrum(wl, K, "1/mm"), "layer": spec}


class CosmeticMap(Node):
    """Region masks → the cosmetic map: per-pixel thickness of each layer (Huang 2013 §3.1).

    ``regions`` (one Mask per layer, bottom layer first) times ``thickness_mm`` (mm, one per
    layer) gives an H×W×n Image of thicknesses in mm (channel i = layer i), as KMStack and
    CosmeticShade take; ``feather_px`` softens the region edges (Gaussian σ in pixels).  Where the optional ``exclude`` mask is 1 (e.g. the eyes) every layer
    is removed: thickness × (1 − exclude).
    """

    version = "2"
    inputs = {"regions": In(Mask, "one region per layer, bottom layer first", variadic=True, min_items=1),
              "exclude": In(Mask, "no cosmetic here (e.g. eyes)", optional=True)}
    outputs = {"thickness": Out(Image, "H×W×n layer thicknesses, mm")}

    class Params(Node.Params):
        thickness_mm: list[float] = Field(description="thickness of each layer where its mask is 1, mm")
        feather_px: float = Field(0.0, ge=0, le=100, description="Gaussian blur (σ, pixels) of the region edges")

    def compute(self, regions: list[Mask], exclude: Mask | None = None):
        p = self.params
        if len(p.thickness_mm) != len(regions):
            raise BadInput("thickness_mm", f"{len(p.thickness_mm)} thicknesses for {len(regions)} regions")
        if any(t < 0 or not np.isfinite(t) for t in p.thickness_mm):
            raise BadInput("thickness_mm", "thicknesses must be finite and ≥ 0 mm")
        shape = regions[0].alpha.shape
        for i, m in enumerate(regions):
            if m.alpha.shape != shape:
                raise BadInput("regions", f"region {i} is {m.alpha.shape[1]}×{m.alpha.shape[0]} px, region 0 is "
                               f"{shape[1]}×{shape[0]} px")
        def soft(a):
            a = np.clip(a, 0, 1).astype(np.float32)
            if p.feather_px > 0:
                from nodes.common.filters import gaussian_blur   # (the same bytes on every CPU)

                a = gaussian_blur(a, p.feather_px)
            return a

        t = np.stack([soft(m.alpha) * np.float32(d) for m, d in zip(regions, p.thickness_mm)], axis=-1)
        if exclude is not None:
            if exclude.alpha.shape != shape:
                raise BadInput("exclude", f"exclude mask is {exclude.width}×{exclude.height} px, the regions are "
                               f"{shape[1]}×{shape[0]} px")
            t *= (1 - np.clip(exclude.alpha, 0, 1))[..., None]
        return Image(t, "thickness_mm")
