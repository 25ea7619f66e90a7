"""The Phong model of Paris, Sillion, Quan 2003 §4 (one copy, used by FitSkinPhong and Render).

    I_X(v) = X_l^A X_m^A + X_l^D X_m^D (l·n) + X_l^S X_m^S (r·v)^s        (§4)

with, for skin (§4.2), ambient colour = diffuse colour = (r, g, b)_skin and specular colour
(i_s, i_s, i_s).  Directions are unit vectors from the surface: n normal, l towards the light,
v towards the viewer, r = 2 (n·l) n − l the mirror direction of l.  The specular term is zero
where the light is behind the surface (n·l ≤ 0).  Unitless (linear RGB relative to the flash).
"""
from __future__ import annotations

import numpy as np


def unit(v: np.ndarray) -> np.ndarray:
    """Normalise vectors along the last axis (zero vectors stay zero)."""
    v = np.asarray(v, np.float64)
    n = np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a·b along the last axis (of 3): the sum of ``np.sum(a * b, axis=-1)`` in its order, bit
    for bit, element-wise (a reduction along an axis of 3 is several times slower)."""
    a, b = np.asarray(a), np.asarray(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def lobes(n: np.ndarray, l: np.ndarray, v: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse factor max(n·l, 0) and specular factor max(r·v, 0)^s (both (...,))."""
    nl = dot(n, l)
    r = 2.0 * nl[..., None] * n - l
    rv = np.clip(dot(r, v), 0.0, None)
    lit = nl > 0
    diff = np.where(lit, nl, 0.0)
    with np.errstate(divide="ignore", invalid="ignore", under="ignore"):
        spec = np.where(lit & (rv > 0), rv ** float(s), 0.0)
    return diff, spec


def shade(kd: np.ndarray, i_s: float, ambient: np.ndarray, light_rgb: np.ndarray,
          diff: np.ndarray, spec: np.ndarray) -> np.ndarray:
    """Phong radiance (..., 3) from the lobes of one light: kd·(A + L·diff) + i_s·L·spec."""
    kd = np.asarray(kd, np.float64)
    L = np.asarray(light_rgb, np.float64)
    return kd * (np.asarray(ambient, np.float64) + L * diff[..., None]) + i_s * L * spec[..., None]
