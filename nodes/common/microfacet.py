"""Microfacet specular shared by the skin (Jimenez) and cosmetics (Huang) nodes.

One implementation of:

* :func:`beckmann_D` — the normalised Beckmann normal distribution function (NDF),
* :func:`schlick_fresnel` — Schlick's approximation of the Fresnel reflectance,
* :func:`kelemen_specular` — the Kelemen/Szirmay-Kalos specular term as used for skin by
  d'Eon & Luebke, *Advanced Techniques for Realistic Real-Time Skin Rendering*, GPU Gems 3
  ch. 14 (§14.3, ``KS_Skin_Specular``) and by Huang et al. 2013 §3.3, eq. 5.

Conventions (all angles in radians, vectors are unit length, last axis of size 3):

``m`` is the Beckmann roughness in the form ``D ∝ exp(-tan²θ_h / m²)``.  It is the 2-D RMS
slope of the microfacets, sqrt(E[s_x² + s_y²]); the RMS slope along one tangent axis is
m/√2.  Mitsuba 3's ``MicrofacetDistribution(MicrofacetType.Beckmann, alpha)`` uses the same
formula with ``alpha = m`` (checked in tests/test_microfacet.py against ``mi.MicrofacetDistribution.eval``),
i.e. Mitsuba's alpha = √2 × the per-axis RMS slope.  GPU Gems 3's ``m`` (0.3 … 0.35 for skin)
is this same ``m``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["beckmann_D", "schlick_fresnel", "kelemen_specular", "kelemen_brdf"]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a·b over the last axis, broadcasting the rest.  One per-pixel array against one vector
    (a directional light, an orthographic viewer) goes through matmul: np.sum(a * b, -1)
    makes an (…, 3) temporary and reduces over an axis of 3, several times slower."""
    if b.ndim == 1:
        return a @ b
    if a.ndim == 1:
        return b @ a
    return np.einsum("...i,...i->...", a, b)


def beckmann_D(cos_theta_h, m, dtype=np.float64):
    """Normalised Beckmann NDF  D(θ_h) = exp(−tan²θ_h / m²) / (π m² cos⁴θ_h).

    ``cos_theta_h`` = N·H (scalar or array), ``m`` = RMS slope (unitless, > 0; see the
    module docstring).  Normalised so that ∫ D(ω_h) cos θ_h dω_h = 1 over the hemisphere.
    Returns 0 where cos θ_h ≤ 0 (back-facing microfacets) and where cos²θ_h is below √(the
    smallest normal number of ``dtype``): D has underflowed to 0 there, and cos⁴θ_h would
    underflow to 0 as well (0/0).  Computed and returned in ``dtype`` (float64, the
    reference, or float32 for per-pixel images: relative error ~1e-6/m² then).
    """
    dtype = np.dtype(dtype).type
    c = np.asarray(cos_theta_h, dtype=dtype)
    m2 = np.square(np.asarray(m, dtype=dtype))
    c2 = c * c
    pos = (c > 0) & (c2 > np.sqrt(np.finfo(dtype).tiny))
    c2s = np.where(pos, c2, dtype(1))
    d = _inplace(np.divide, np.subtract(dtype(1), c2s), c2s)  # tan²θ_h
    d = np.exp(_inplace(np.divide, _inplace(np.negative, d), m2), out=d if _owned(d) else None)
    d = _inplace(np.divide, d, _inplace(np.multiply, c2s * c2s, np.pi * m2))
    return _inplace(np.multiply, d, pos)              # 0 where not pos (d is finite there)


def _owned(a) -> bool:
    """Whether ``a`` is an array this module made (results may be written into it)."""
    return isinstance(a, np.ndarray) and a.ndim > 0


def _inplace(op, a, b=None):
    """op(a, b) (or op(a)), written into ``a`` when it is an array of the result's shape and type:
    the same values as op(a, b) without a new array per step."""
    args = (a,) if b is None else (a, b)
    if _owned(a) and np.broadcast_shapes(a.shape, np.shape(b)) == a.shape and np.result_type(*args) == a.dtype:
        return op(*args, out=a)
    return op(*args)


def schlick_fresnel(cos_theta, f0, dtype=np.float64):
    """Schlick's Fresnel approximation  F = f0 + (1 − f0)(1 − cos θ)⁵.

    ``cos_theta`` is the cosine between the view (or light) direction and the half vector
    (clipped to [0, 1]); ``f0`` is the reflectance at normal incidence (0.028 for skin,
    i.e. n ≈ 1.4).  Unitless; computed in ``dtype``.
    """
    dtype = np.dtype(dtype).type
    c = np.clip(np.asarray(cos_theta, dtype=dtype), 0, 1)
    e = (1 - c) ** 5
    return e + np.asarray(f0, dtype=dtype) * (1 - e)


def _kelemen(n, l, v, m, f0, dtype):
    """(f_r, N·L) of :func:`kelemen_brdf` in ``dtype``.  H, |L + V|² and the Fresnel term have
    the broadcast shape of l and v only: for a directional light and an orthographic viewer
    they are computed once, and only N·H and N·L are per pixel."""
    dtype = np.dtype(dtype).type
    n, l, v = (np.asarray(x, dtype=dtype) for x in (n, l, v))
    h = l + v
    hh = _dot(h, h)
    hok = hh > 1e-12
    hh_s = np.where(hok, hh, dtype(1))
    H = h / np.sqrt(hh_s)[..., None]
    ndotl = _dot(n, l)
    ok = hok & (ndotl > 0)
    f = _inplace(np.multiply, beckmann_D(_dot(n, H), m, dtype), schlick_fresnel(_dot(H, l), f0, dtype) / hh_s)
    return _inplace(np.multiply, _inplace(np.maximum, f, dtype(0)), ok), ndotl


def kelemen_brdf(n, l, v, m, f0=0.028, dtype=np.float64):
    """Kelemen/Szirmay-Kalos specular BRDF  f_r = D(H) F(H·L) / |L + V|²  (sr⁻¹).

    This is Huang 2013 eq. 5, f_r = P_H(H) F(H·L) / (2(1 + L·V)), since |L + V|² = 2(1 + L·V),
    with P_H the normalised Beckmann NDF :func:`beckmann_D`.  ``n``, ``l``, ``v`` are unit
    vectors (…, 3) (l towards the light, v towards the viewer); returns (…) in ``dtype``.
    Zero where N·L ≤ 0 or L = −V.
    """
    return _kelemen(n, l, v, m, f0, dtype)[0]


def kelemen_specular(n, l, v, m, rho_s, f0=0.028, dtype=np.float64):
    """Kelemen/Szirmay-Kalos specular term as in GPU Gems 3 ch. 14 (``KS_Skin_Specular``).

    Returns ``rho_s · π · f_r(L, V) · max(N·L, 0)`` with f_r = :func:`kelemen_brdf`, i.e.
    exactly d'Eon & Luebke's ``ndotl * rho_s * PH * F / dot(h, h)`` where their ``PH`` is the
    Beckmann NDF without the 1/π factor.  This is the reflected radiance per unit light in the
    GPU Gems convention where a white Lambertian surface returns max(N·L, 0) (diffuse =
    albedo · N·L, no 1/π), so it adds directly to such a diffuse term.

    ``n``, ``l``, ``v``: unit vectors (…, 3) — normal, direction to the light, direction to the
    viewer; ``m``: Beckmann RMS slope (unitless; 0.3 … 0.35 for skin); ``rho_s``: specular
    intensity (unitless; ≈ 0.18 for skin in GPU Gems 3); ``f0``: Fresnel reflectance at normal
    incidence (0.028 for skin).  ``m``, ``rho_s``, ``f0`` may be arrays broadcasting with (…).
    Returns (…) in ``dtype``: float64 (the reference) by default; SkinShade passes float32
    for its per-pixel normals (same maths, float32 rounding, no float64 temporaries).
    """
    dtype = np.dtype(dtype).type
    f, ndotl = _kelemen(n, l, v, m, f0, dtype)
    f = _inplace(np.multiply, f, np.asarray(rho_s, dtype=dtype) * dtype(np.pi))
    return _inplace(np.multiply, f, _inplace(np.maximum, ndotl, dtype(0)))
