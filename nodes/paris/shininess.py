"""ShininessFromSaturation — the Phong exponent from the size of the highlight (Paris 2003 §4.2)."""
from __future__ import annotations

from typing import Literal

import numpy as np

from graphkit import BadInput, Field, Image, In, Light, Node, Out, Scalar

from . import sphere


class ShininessFromSaturation(Node):
    """Phong exponent s from the reflectance map's highlight (Paris 2003 §4.2, eqs. (1)–(3)).

    The highlight sits at the normal halfway between the light and the view direction (the
    camera, −z).  Along the great circle through it towards the left and the right (the
    image-plane horizontal), the angle α of the fastest saturation change is found on each
    side; their mean is α_sat^max and, with ζ = sin α_sat^max, eq. (3)

        s = (4ζ⁴ − 2ζ² − 1 − √(−16ζ⁶ + 8ζ⁴ + 1)) / (8ζ²(ζ − 1)(ζ + 1)),

    the inflection of ρ(α) = cos^s(2α)/cos(α), eq. (2), solved for s.

    The map is first divided by the light's colour (so the flash is white).  ``measure``:

    * ``"inverse"`` (default) — the fastest *decrease* of 1/S, where S = (max − min)/max is the
      HSV saturation.  A pixel mixing skin colour C and white flash, c = cos α·(C + ρ·(1,1,1)),
      has 1/S = (C_max + ρ)/(C_max − C_min): affine in ρ, so its fastest change is exactly the
      largest change of ρ, eq. (1), whatever the skin colour and the specular intensity.
    * ``"hsv"`` — the fastest increase of S itself, as the paper words it (S is a monotone but
      non-linear function of ρ, so this shifts α_sat with the specular/diffuse ratio).

    The profile is read from the map by cubic interpolation (pole- and azimuth-aware) every
    ``step_deg`` (default: the map resolution / 8) and the peak of its derivative is refined to
    sub-sample precision.  The steep slope of eq. (3) (paper Fig. 2) makes high exponents need
    precise profiles: s = 150 puts α_sat at 2.3°, so ±10% in s needs α within ±0.12°; the
    cubic reading makes the paper's 1° map enough (checked against POV-Ray for s = 5…150).

    Inputs: ``reflectance`` in the Gaussian-sphere layout of :mod:`nodes.paris.sphere` (rows θ,
    columns φ, resolution 180/rows degrees), ``light`` in the same camera frame.  Output: s
    (unitless).  Units: angles in degrees.
    """

    version = "1"
    inputs = {"reflectance": In(Image, "reflectance map on the Gaussian sphere (nodes.paris.sphere layout)"),
              "light": In(Light, "the flash of the photo (direction towards the light, camera frame)")}
    outputs = {"shininess": Out(Scalar, "Phong exponent s (unitless)")}

    class Params(Node.Params):
        measure: Literal["inverse", "hsv"] = Field("inverse", description="saturation measure (see the docstring)")
        max_angle_deg: float = Field(40.0, gt=1, le=44, description="how far from the highlight to look (degrees)")
        step_deg: float | None = Field(None, gt=0, description="profile sampling step (degrees); default: map resolution / 8")
        smooth_deg: float = Field(0.0, ge=0, description="Gaussian smoothing of the profile before differentiating (degrees)")

    def compute(self, reflectance: Image, light: Light):
        rmap = np.asarray(reflectance.pixels, np.float64)
        rows, cols, ch = rmap.shape
        if cols != 2 * rows or ch < 3:
            raise BadInput("reflectance", f"a reflectance map is rows × 2·rows × 3 (θ × φ × RGB), got "
                                          f"{cols}×{rows}×{ch}")
        if not np.isfinite(rmap).all():
            raise BadInput("reflectance", "the map holds NaN or Inf values")
        res = 180.0 / rows
        color = np.asarray(light.color, np.float64)
        if not (color > 0).all():
            raise BadInput("light", f"the light colour {tuple(color)} must be positive in every channel")
        wb = rmap[..., :3] / (color / color.max())
        h = highlight_normal(light.direction)
        if h[2] > -np.cos(np.radians(80)):
            raise BadInput("light", "the highlight is at the rim of the visible hemisphere or beyond: "
                                    "the light is too far from the camera (or behind the face)")
        step = self.params.step_deg or res / 8
        alphas = np.arange(0.0, self.params.max_angle_deg + step / 2, step)
        sides = []
        for sign in (+1, -1):
            n = great_circle(h, sign, np.radians(alphas))
            rgb = sample_cubic(wb, n, res)
            sides.append(fastest_change(alphas, rgb, self.params.measure, self.params.smooth_deg / step))
        if any(a is None for a in sides):
            raise BadInput("reflectance", "no highlight: the saturation does not change around the "
                                          "highlight direction given by the light")
        a_sat = 0.5 * (sides[0] + sides[1])
        s = shininess_from_angle(np.radians(a_sat))
        if not np.isfinite(s) or s <= 0:
            raise BadInput("reflectance", f"the fastest saturation change is {a_sat:.1f}° from the "
                                          "highlight, which no Phong exponent gives (eq. 3)")
        return float(s)


def shininess_from_angle(alpha: float | np.ndarray) -> float | np.ndarray:
    """Eq. (3): Phong exponent s whose ρ(α) = cos^s(2α)/cos α has its inflection at α (radians)."""
    z = np.sin(alpha)
    z2 = z * z
    with np.errstate(invalid="ignore", divide="ignore"):
        return (4 * z2 * z2 - 2 * z2 - 1 - np.sqrt(-16 * z2 ** 3 + 8 * z2 * z2 + 1)) / (8 * z2 * (z - 1) * (z + 1))


def highlight_normal(direction) -> np.ndarray:
    """Normal of the highlight: halfway between the light and the camera (−z), unit."""
    l = np.asarray(direction, np.float64)
    nl = np.linalg.norm(l)
    if not np.isfinite(nl) or nl == 0:
        raise BadInput("light", "the light direction is zero or not finite")
    hv = l / nl + np.array([0.0, 0.0, -1.0])
    nh = np.linalg.norm(hv)
    if nh < 1e-6:
        raise BadInput("light", "the light is exactly behind the face")
    return hv / nh


def great_circle(h: np.ndarray, sign: int, alpha: np.ndarray) -> np.ndarray:
    """Normals at angles α (radians) from h towards the image-plane right (+1) or left (−1)."""
    x = np.array([1.0, 0.0, 0.0])
    t = x - (x @ h) * h
    t /= np.linalg.norm(t)
    return np.cos(alpha)[:, None] * h + sign * np.sin(alpha)[:, None] * t


def sample_cubic(rmap: np.ndarray, n: np.ndarray, res: float) -> np.ndarray:
    """Cubic-spline lookup of a Gaussian-sphere map at unit normals (N×3) → (N×C).

    The map is padded across the pole (θ < 0 is θ > 0 at φ + 180°) and around φ (periodic)
    before interpolating, so profiles through the pole are smooth."""
    from scipy import ndimage

    rows, cols, ch = rmap.shape
    pad = 4
    half = cols // 2
    top = np.roll(rmap[:pad][::-1], half, axis=1)
    bot = np.roll(rmap[-pad:][::-1], half, axis=1)
    m = np.concatenate([top, rmap, bot], 0)
    m = np.concatenate([m[:, -pad:], m, m[:, :pad]], 1)
    fr, fc = sphere.normals_to_pixels(n, res)
    r = fr - 0.5 + pad
    c = np.mod(fc - 0.5, cols) + pad
    return np.stack([ndimage.map_coordinates(m[..., k], [r, c], order=3, mode="nearest")
                     for k in range(ch)], -1)


def fastest_change(alphas: np.ndarray, rgb: np.ndarray, measure: str, smooth: float) -> float | None:
    """Angle (degrees) where the saturation profile changes fastest away from the highlight."""
    from scipy import ndimage

    mx = rgb.max(-1)
    mn = rgb.min(-1)
    spread = np.maximum(mx - mn, 1e-9)
    if measure == "inverse":
        y = -(mx / spread)          # −1/S: increases away from the highlight
    else:
        y = spread / np.maximum(mx, 1e-12)
    if smooth > 0:
        y = ndimage.gaussian_filter1d(y, smooth, mode="nearest")
    d = np.gradient(y, alphas)
    if not np.isfinite(d).all() or np.ptp(y) <= 1e-6 * max(np.abs(y).max(), 1e-12):
        return None
    k = int(np.argmax(d[1:-1])) + 1
    if d[k] <= 0:
        return None
    dm, d0, dp = d[k - 1], d[k], d[k + 1]
    den = dm - 2 * d0 + dp
    off = 0.5 * (dm - dp) / den if den < 0 else 0.0
    return float(alphas[k] + np.clip(off, -1, 1) * (alphas[1] - alphas[0]))
