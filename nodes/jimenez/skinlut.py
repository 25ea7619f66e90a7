"""Spectral two-layer skin model and the skin colour lookup table (Jimenez et al. 2010 §6,
table 1, eq. 7; spectral model after Donner & Jensen 2006 / Donner et al. 2008).

Units (all lengths in **mm**, wavelengths λ in **nm**, absorption/scattering in **mm⁻¹**):

* eumelanin   σa_em(λ) = 6.6·10¹⁰ · λ^−3.33 mm⁻¹   (Jacques' 6.6·10¹¹ λ^−3.33 cm⁻¹; 67.9 mm⁻¹ at 500 nm)
* pheomelanin σa_pm(λ) = 2.9·10¹⁴ · λ^−4.75 mm⁻¹   (Donner & Jensen 2006's coefficient.  The
  two public implementations of that paper found (pbrt-based skin materials on GitHub) use it
  unchanged beside 6.6·10¹⁰ for eumelanin, i.e. in the same mm⁻¹ as the eumelanin term above;
  the paper's text was not available to check.  Version 1 divided it by 10, which made
  pheomelanin 13–23× weaker than eumelanin over 450–650 nm instead of 1.3–2.3×.)
* baseline    σa_base(λ) = 0.0244 + 8.53 · exp(−(λ − 154)/66.2) mm⁻¹ (Jacques, bloodless tissue)
* hemoglobin  σa_hb(λ) = ln(10) · ε(λ) · 150 g/L / 64 500 g/mol, ε in cm⁻¹/M from Prahl's table
  (data/hemoglobin_prahl.csv), ÷10 to mm⁻¹; blood oxygenation γ = 0.75 mixes HbO₂ and Hb.
* reduced scattering σs′_epi(λ) = 14.74 λ^−0.22 + 2.2·10¹¹ λ^−4 mm⁻¹; the dermis has the same
  (``km``, ``filter``) or half of it (``multipole``, as Donner & Jensen 2006).

Volume fractions (unitless): C_m melanin, β_m eumelanin share of melanin, C_he and C_hd
hemoglobin in epidermis and dermis.  Table 1 ranges: C_m 0–0.5, β_m 0–1, C_he 0–0.1,
C_hd 0–0.32; the table uses C_he = 0.25 C_hd (§6).

Total diffuse reflectance: the dermis is a semi-infinite scattering medium (Jensen et al.
2001 dipole, integrated over the surface, η = 1.4).  The epidermis (thickness ``d_epi`` mm)
is a layer that scatters as well as absorbs, added to the dermis as
R = R₁ + T₁² R₂ / (1 − R₁ R₂) (the layer-adding rule Donner & Jensen use).  Its R₁, T₁ come
by default (``"km"``) from the Kubelka–Munk two-flux solution for a slab (Kubelka 1948, the
theory of the Cotton & Claridge model behind the paper's acquisition, §3), with
K = 2 σa and S = ¾ σs′ − ¼ σa (Star, Marijnissen & van Gemert 1988, Phys. Med. Biol. 33:437),
and ``d_epi`` = 0.06 mm: the cellular (melanin-bearing) epidermis is 56.6 ± 11.5 µm on the
forearm (Sandby-Møller, Poulsen & Wulf 2003, Acta Derm. Venereol. 83:410).

Why a scattering epidermis: melanin sits inside scattering tissue, so reflectance varies
roughly with √σa rather than with exp(−σa·path); an absorbing filter over the dermis
(``"filter"``, T = exp(−2 σa d) per crossing, the previous default) exaggerates melanin's blue
absorption and makes dark skin far too saturated (ColorChecker dark skin ΔE00 8.4 at the
best β_m; at its nearest entry the filter leaves 0.1 % reflectance at 420 nm where the
measured patch keeps 6 %).  The diffusion multipole of Donner & Jensen 2005 (``"multipole"``,
kept as an option, d = 0.25 mm) puts its source 1/σt′ = 0.11–0.23 mm deep (450–700 nm), i.e.
below an epidermis of realistic thickness, so it is not usable at 0.06–0.1 mm; the two-flux
slab is.  The dermis scatters like the epidermis (σs′ above); Donner & Jensen 2006 halve it,
which makes light skin too dark (nodes/jimenez/README.md reports the numbers).  Spectra →
CIE XYZ (D65, CIE 1931 2°) → linear sRGB with colour-science.
"""
from __future__ import annotations

import functools
import os
from typing import Literal

import numpy as np

from graphkit import Array, Field, Image, Node, Out, Vector

CM_MAX = 0.5    # table 1
CHD_MAX = 0.32  # table 1
WL = np.arange(380.0, 781.0, 5.0)  # nm


@functools.lru_cache(maxsize=1)
def prahl_table() -> np.ndarray:
    """(n, 3): wavelength nm, ε(HbO₂), ε(Hb) in cm⁻¹/M (Prahl, omlc.org; via MNE-Python)."""
    path = os.path.join(os.path.dirname(__file__), "data", "hemoglobin_prahl.csv")
    return np.loadtxt(path, delimiter=",", comments="#", skiprows=7)


def eumelanin_absorption(wl_nm):
    """σa of eumelanin, mm⁻¹ (λ in nm)."""
    return 6.6e10 * np.asarray(wl_nm, np.float64) ** -3.33


def pheomelanin_absorption(wl_nm):
    """σa of pheomelanin, mm⁻¹ (λ in nm)."""
    return 2.9e14 * np.asarray(wl_nm, np.float64) ** -4.75


def baseline_absorption(wl_nm):
    """σa of bloodless, melanin-free skin, mm⁻¹ (λ in nm)."""
    return 0.0244 + 8.53 * np.exp(-(np.asarray(wl_nm, np.float64) - 154.0) / 66.2)


def hemoglobin_absorption(wl_nm, oxygenation: float = 0.75):
    """σa of whole blood (150 g/L hemoglobin), mm⁻¹, from Prahl's molar extinction table."""
    t = prahl_table()
    wl = np.asarray(wl_nm, np.float64)
    hbo2 = np.interp(wl, t[:, 0], t[:, 1])
    hb = np.interp(wl, t[:, 0], t[:, 2])
    eps = oxygenation * hbo2 + (1 - oxygenation) * hb  # cm⁻¹/M
    return np.log(10.0) * eps * 150.0 / 64500.0 / 10.0


def reduced_scattering_epidermis(wl_nm):
    """σs′ of the epidermis, mm⁻¹ (dermis: half of it)."""
    wl = np.asarray(wl_nm, np.float64)
    return 14.74 * wl ** -0.22 + 2.2e11 * wl ** -4.0


def _A(eta: float) -> float:
    fdr = -1.440 / eta ** 2 + 0.710 / eta + 0.668 + 0.0636 * eta
    return (1 + fdr) / (1 - fdr)


def _slab_RT(sa, ss, d, eta=1.4, n_pairs=6):
    """Total diffuse R and T of a slab of thickness d (mm): r-integrated multipole."""
    st = sa + ss
    alpha = ss / st
    D = 1.0 / (3.0 * st)
    sigtr = np.sqrt(sa / D)
    zb = 2.0 * _A(eta) * D
    l = 1.0 / st
    R = np.zeros(np.broadcast(sa, d).shape)
    T = np.zeros_like(R)
    for i in range(-n_pairs, n_pairs + 1):
        zr = 2 * i * (d + 2 * zb) + l
        zv = 2 * i * (d + 2 * zb) - l - 2 * zb
        R += np.sign(zr) * np.exp(-sigtr * np.abs(zr)) - np.sign(zv) * np.exp(-sigtr * np.abs(zv))
        T += (np.sign(d - zr) * np.exp(-sigtr * np.abs(d - zr))
              - np.sign(d - zv) * np.exp(-sigtr * np.abs(d - zv)))
    return np.clip(alpha / 2 * R, 0, 1), np.clip(alpha / 2 * T, 0, 1)


def _km_slab_RT(sa, ss, d):
    """Kubelka–Munk diffuse R and T of a slab of thickness d (mm), σa and σs′ in mm⁻¹.

    K = 2σa, S = ¾σs′ − ¼σa (Star et al. 1988); a = 1 + K/S, b = √(a² − 1):
    R = sinh(bSd) / (a sinh(bSd) + b cosh(bSd)), T = b / (same).
    """
    K = 2.0 * sa
    Sk = np.maximum(0.75 * ss - 0.25 * sa, 1e-9)
    a = 1.0 + K / Sk
    b = np.sqrt(a * a - 1.0)
    x = b * Sk * d
    den = a * np.sinh(x) + b * np.cosh(x)
    return np.sinh(x) / den, b / den


def _semi_infinite_R(sa, ss, eta=1.4):
    """Total diffuse reflectance of a semi-infinite medium (r-integrated dipole)."""
    st = sa + ss
    alpha = ss / st
    x = np.sqrt(3 * (1 - alpha))
    return alpha / 2 * (1 + np.exp(-4.0 / 3.0 * _A(eta) * x)) * np.exp(-x)


def skin_reflectance(c_m, c_hd, beta_m=0.61, c_he=None, wl=WL, d_epi=None, oxygenation=0.75,
                     epidermis: str = "km"):
    """Total diffuse reflectance (…, n_wl) of two-layer skin for volume fractions C_m, C_hd.

    ``c_he`` defaults to 0.25·C_hd (§6).  ``d_epi`` in mm (default 0.06 for ``km``, 0.1 for
    ``filter``, 0.25 for ``multipole``), ``wl`` in nm.  ``epidermis``:

    * ``"km"`` (default): the epidermis is a scattering, absorbing Kubelka–Munk slab (σs′ as
      below) over a semi-infinite dipole dermis with the same σs′, added as
      R₁ + T₁² R₂ / (1 − R₁R₂) (module docstring).
    * ``"filter"``: the thin epidermis is an absorbing filter crossed twice by
      diffuse light, T = exp(−2 σa_epi d_epi) per crossing (mean diffuse path 2d), over a
      semi-infinite dermis (dipole, σs′ as the epidermis): R = T² R_derm.
    * ``"multipole"``: the epidermis is a scattering multipole slab (σs′_epi), the dermis a
      dipole with half that scattering, added as R₁ + T₁² R₂ / (1 − R₁R₂) (Donner & Jensen).
    """
    c_m = np.asarray(c_m, np.float64)[..., None]
    c_hd = np.asarray(c_hd, np.float64)[..., None]
    c_he = 0.25 * c_hd if c_he is None else np.asarray(c_he, np.float64)[..., None]
    wl = np.asarray(wl, np.float64)
    mel = beta_m * eumelanin_absorption(wl) + (1 - beta_m) * pheomelanin_absorption(wl)
    hem = hemoglobin_absorption(wl, oxygenation)
    base = baseline_absorption(wl)
    sa_epi = c_m * mel + c_he * hem + (1 - c_m - c_he) * base
    sa_derm = c_hd * hem + (1 - c_hd) * base
    ss = reduced_scattering_epidermis(wl)
    if epidermis == "km":
        d = 0.06 if d_epi is None else d_epi
        R1, T1 = _km_slab_RT(sa_epi, ss, d)
        R2 = _semi_infinite_R(sa_derm, ss)
        return R1 + T1 * T1 * R2 / (1 - R1 * R2)
    if epidermis == "filter":
        d = 0.1 if d_epi is None else d_epi
        T = np.exp(-2.0 * sa_epi * d)
        return T * T * _semi_infinite_R(sa_derm, ss)
    if epidermis != "multipole":
        raise ValueError(f"unknown epidermis model {epidermis!r}")
    d = 0.25 if d_epi is None else d_epi
    R1, T1 = _slab_RT(sa_epi, ss, d)
    R2 = _semi_infinite_R(sa_derm, 0.5 * ss)
    return R1 + T1 * T1 * R2 / (1 - R1 * R2)


@functools.lru_cache(maxsize=4)
def _cmfs_and_illuminant(start: float, end: float, interval: float):
    import colour

    from nodes.common import color as _color  # noqa: F401  (keeps colour's warning filter)

    shape = colour.SpectralShape(start, end, interval)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    return shape, cmfs, ill


def reflectance_to_linear_srgb(refl: np.ndarray, wl=WL) -> np.ndarray:
    """Reflectance spectra (…, n_wl) → linear sRGB under D65 (colour-science, CIE 1931 2°)."""
    import colour

    shape, cmfs, ill = _cmfs_and_illuminant(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    flat = np.asarray(refl, np.float64).reshape(-1, len(wl))
    xyz = colour.msds_to_XYZ(flat, cmfs, ill, method="Integration", shape=shape) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    return np.asarray(rgb).reshape(np.shape(refl)[:-1] + (3,))


def lut_axes(size_u: int, size_v: int) -> tuple[np.ndarray, np.ndarray]:
    """C_m along u and C_hd along v sampled cubically (eq. 7: u = ∛C_m, v = ∛C_hd)."""
    u = np.linspace(0.0, np.cbrt(CM_MAX), size_u)
    v = np.linspace(0.0, np.cbrt(CHD_MAX), size_v)
    return u ** 3, v ** 3


def lut_corners(lut: np.ndarray) -> np.ndarray:
    """The table as bilinear cell coefficients, float32 (4, n_v, n_u, C): for the cell whose
    lower corner is entry (v, u), with c_ab = lut[v + b, u + a] (clamped at the last row and
    column), the tables c00, c10 − c00, c01 − c00 and c11 − c10 − c01 + c00, so that
    value(a, b) = c00 + a (c10 − c00) + b ((c01 − c00) + a (c11 − c10 − c01 + c00))."""
    t = np.asarray(lut, np.float64)
    nv, nu, nc = t.shape
    c10 = t[:, np.minimum(np.arange(nu) + 1, nu - 1)]
    c01 = t[np.minimum(np.arange(nv) + 1, nv - 1)]
    c11 = c01[:, np.minimum(np.arange(nu) + 1, nu - 1)]
    return np.ascontiguousarray(np.stack([t, c10 - t, c01 - t, c11 - c10 - c01 + t]), np.float32)


_ROW = 1024  # pixels per row when a map is not a 2-D image cv2 can take as it is


def lut_lookup(lut: np.ndarray, c_m: np.ndarray, c_hd: np.ndarray, corners: np.ndarray | None = None) -> np.ndarray:
    """Bilinear lookup of an (n_v, n_u, C) table at volume fractions (eq. 7), float32.

    u = ∛C_m / ∛0.5 and v = ∛C_hd / ∛0.32 in table coordinates; values outside table 1's
    ranges are clamped to its edges.  Returns the broadcast shape of the maps + (C,).

    Float32 throughout, equal to a float64 bilinear lookup within float32 rounding
    (tests/oracles/test_jimenez_lut.py): coordinates by cv2.pow (~3e-7 relative error, ~10×
    faster than np.cbrt), the cell of each pixel as whole-number float maps, the four tables
    of :func:`lut_corners` (pass ``corners`` to reuse them across calls) gathered there by
    cv2.remap INTER_NEAREST (an exact gather, ~3× faster than np.take), and the bilinear form
    on contiguous (…, C) arrays (weights expanded to C channels by cv2.merge: numpy is several
    times slower broadcasting (…, 1) against (…, 3)).  cv2.remap's own INTER_LINEAR is not
    used: it quantises the fractional coordinates to 1/32 of a cell.
    """
    import cv2

    c_m, c_hd = np.broadcast_arrays(np.asarray(c_m, np.float32), np.asarray(c_hd, np.float32))
    shape = c_m.shape
    nv, nu, nc = np.shape(lut)
    coef = lut_corners(lut) if corners is None else corners
    if len(shape) == 2 and 0 < shape[0] < 32767 and 0 < shape[1] < 32767:  # cv2's limit on map sizes
        maps = (c_m, c_hd)
    else:  # as rows of _ROW pixels, the last one padded
        n = c_m.size
        pad = -n % _ROW
        maps = tuple(np.pad(x.reshape(-1), (0, pad)).reshape(-1, _ROW) for x in (c_m, c_hd))
        if maps[0].shape[0] >= 32767:
            h = 32766 * _ROW  # that many pixels at a time
            parts = [lut_lookup(lut, c_m.reshape(-1)[s:s + h], c_hd.reshape(-1)[s:s + h], coef)
                     for s in range(0, n, h)]
            return np.concatenate(parts).reshape(shape + (nc,))
    (fu, u0), (fv, v0) = (_cell(x, c_max, size) for x, c_max, size in
                          ((maps[0], CM_MAX, nu), (maps[1], CHD_MAX, nv)))
    a = fu - u0  # in [0, 1] up to rounding at the last entry
    b = fv - v0
    if nc > 1:
        a, b = cv2.merge([a] * nc), cv2.merge([b] * nc)
    else:
        a, b = a[..., None], b[..., None]

    def gather(k):
        g = cv2.remap(coef[k], u0, v0, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return g.reshape(u0.shape + (nc,))

    out = gather(3)
    out *= a
    out += gather(2)
    out *= b
    out += gather(0)
    d = gather(1)
    d *= a
    out += d
    if out.shape[:2] != shape:
        out = out.reshape(-1, nc)[:c_m.size]
    return out.reshape(shape + (nc,))


def _cell(c: np.ndarray, c_max: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(f, f0): the table coordinate f = (n − 1)·∛(clip(c, 0, c_max) / c_max) of a 2-D float32
    map and its cell min(⌊f⌋, n − 2) ≥ 0 as whole numbers in float32 (cv2.remap's map type)."""
    import cv2

    f = cv2.pow(np.clip(c, np.float32(0), np.float32(c_max)), 1.0 / 3.0)
    f *= np.float32((n - 1) / np.cbrt(c_max))
    f0 = np.floor(f)
    np.minimum(f0, np.float32(max(n - 2, 0)), out=f0)
    return f, f0


class SkinColorLUT(Node):
    """Skin colour lookup table (Jimenez 2010 §6, table 1, eq. 7, figure 9).

    Each entry is the total diffuse reflectance of the two-layer spectral skin model (module
    docstring: melanin mm⁻¹, Prahl hemoglobin, a scattering epidermis of ``epidermis_mm`` mm
    over a semi-infinite dermis, C_he = 0.25 C_hd) converted to linear sRGB (D65) with colour-science.  Columns
    (u, width) sample melanin C_m ∈ [0, 0.5] as u = ∛C_m, rows (v, height) sample dermal
    hemoglobin C_hd ∈ [0, 0.32] as v = ∛C_hd (eq. 7).  ``reflectance`` holds the spectra
    (rows × columns × wavelengths) at ``wavelengths`` (nm).  ``melanin_blend`` (β_m) is a
    per-subject parameter (table 1: 0–1): lighter skin tends to pheomelanin, darker skin to
    eumelanin, so one table per β_m is the intended use; 0.61 is figure 9's.
    """

    version = "2"
    outputs = {"lut": Out(Image, "linear sRGB albedo, rows = ∛C_hd, columns = ∛C_m"),
               "reflectance": Out(Array, "spectral reflectance, (rows, columns, wavelengths)"),
               "wavelengths": Out(Vector, "wavelengths of the spectra (nm)")}

    class Params(Node.Params):
        size: int = Field(64, ge=2, le=512, description="entries per axis")
        melanin_blend: float = Field(0.61, ge=0, le=1, description="β_m: eumelanin share of melanin (figure 9: 0.61)")
        epidermis_mm: float | None = Field(None, gt=0, le=2, description="epidermis thickness (mm); default per model: km 0.06, filter 0.1, multipole 0.25")
        oxygenation: float = Field(0.75, ge=0, le=1, description="blood oxygen saturation")
        epidermis: Literal["km", "filter", "multipole"] = Field("km", description="epidermis model (module docstring)")

    def compute(self):
        p = self.params
        cm, chd = lut_axes(p.size, p.size)
        refl = skin_reflectance(cm[None, :], chd[:, None], p.melanin_blend, d_epi=p.epidermis_mm,
                                oxygenation=p.oxygenation, epidermis=p.epidermis)
        rgb = reflectance_to_linear_srgb(refl)
        return {"lut": Image(rgb.astype(np.float32)), "reflectance": refl,
                "wavelengths": WL.copy()}
