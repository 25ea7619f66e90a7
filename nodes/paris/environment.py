"""Relighting to an environment (Paris 2003 Fig. 10-b, §6 "complex lighting environment"):
an equirectangular map turned into a few dominant directional lights (Debevec's median cut,
"A median cut algorithm for light probe sampling", 2005) that Render shades (the brightest
of them with shadows), plus an order-2 spherical-harmonic ambient (9 coefficients) for the rest
of the map, shaded by Ramamoorthi and Hanrahan's irradiance formula ("An efficient
representation for irradiance environment maps", 2001).

Units: a Light's colour × intensity is the irradiance it gives divided by π, so a white
Lambertian surface shows the map's own radiance units (under a uniform map of radiance 1 it
shows 1, as it would in Mitsuba).  The SH coefficients are the map's residual radiance.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict

from graphkit import Field, Image, In, Light, Node, Out
from nodes.io.environment import EnvironmentFrame, check_equirect, local_directions, solid_angles

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance of linear RGB
SH_BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])
SH_A = np.array([np.pi, 2 * np.pi / 3, np.pi / 4])  # Â_l, the clamped cosine's SH (R–H eq. 8)


class EnvironmentLighting(BaseModel):
    """An environment as lights: dominant directional ``lights`` (world frame; Render shadows
    those of at least ``environment_shadows`` × the brightest's luminance) and ``sh``, 9 RGB
    spherical-harmonic coefficients (l ≤ 2, real basis, world frame) of the radiance left
    over, which Render adds unshadowed as an ambient."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    lights: tuple[Light, ...] = ()
    sh: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),) * 9

    def energy(self) -> np.ndarray:
        """The RGB integral of radiance over the sphere that these lights and this ambient hold
        (sr × radiance): π × each light's colour × intensity, plus √(4π) × the ambient's first
        coefficient."""
        e = np.sqrt(4 * np.pi) * np.asarray(self.sh[0], np.float64)
        for light in self.lights:
            e = e + np.pi * light.intensity * np.asarray(light.color, np.float64)
        return e


# the real SH basis (l ≤ 2) is SH_K[k] × a polynomial of the direction, in this order (the
# polynomials: sh_basis here, env_irradiance in shaders/glsl/shade.frag; the constants only here)
SH_K = np.array([0.282095, 0.488603, 0.488603, 0.488603, 1.092548, 1.092548, 0.315392,
                 1.092548, 0.546274])


def sh_basis(d: np.ndarray) -> np.ndarray:
    """N×9 real spherical harmonics Y_lm (l ≤ 2) at unit directions d (N×3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    k = SH_K
    return np.stack([np.full_like(x, k[0]), k[1] * y, k[2] * z, k[3] * x,
                     k[4] * x * y, k[5] * y * z, k[6] * (3 * z * z - 1),
                     k[7] * x * z, k[8] * (x * x - y * y)], 1)


def sh_irradiance_weights(sh) -> np.ndarray:
    """9×3: the coefficients that turn sh_basis's polynomials (without SH_K) at a normal into
    sh_irradiance there (Σ_k weight_k × poly_k(n)): SH_K × Â_l / π × the coefficients; the
    GL drivers' uniform (shade.frag ENV_SH)."""
    return np.asarray(sh, np.float64) * (SH_K * SH_A[SH_BAND] / np.pi)[:, None]


def sh_irradiance(sh, normals: np.ndarray) -> np.ndarray:
    """N×3 irradiance / π at unit normals from 9 RGB radiance coefficients (Ramamoorthi and
    Hanrahan 2001: E(n) = Σ Â_l L_lm Y_lm(n)); /π to Render's light units."""
    coef = np.asarray(sh, np.float64) * (SH_A[SH_BAND] / np.pi)[:, None]
    return sh_basis(normals) @ coef


#: an environment light's shadow map: the brightest light's side × (its luminance / the
#: brightest's) ** SIZE_POWER, at least MIN_SIZE of it (see shadow_map_sizes)
SIZE_POWER = 1 / 3
MIN_SIZE = 1 / 8


def shadow_map_sizes(lights, size: int, own: int = 0, dominant: float = 0.0) -> list[int]:
    """The shadow-map side of each of ``lights``: ``size`` for the first ``own`` (lights
    given as such) and for the brightest of the rest (an environment's), smaller for dimmer
    ones, and 0 (no shadow: the light shades unshadowed) for an environment light whose
    luminance is below ``dominant`` × the brightest's (issue 26 item 4: "shadows from the
    dominant ones"; Render's ``environment_shadows``).  A coarser map moves a shadow's edge
    by up to a texel, an error weighed by the light's energy: the sum over lights of
    energy / side, for a cost growing with the texels (side²), is least with
    side ∝ energy^⅓.  Measured against Mitsuba (benchmarks/bench_environment.py, 16 lights):
    every map within 0.01 dB of full-size maps or better; at 1024² the environment's shadow
    maps take ~⅓ of their texels."""
    lum = np.array([light.intensity * float(np.dot(light.color, LUMA)) for light in lights[own:]])
    if len(lum) == 0 or lum.max() <= 0:
        return [size] * len(lights)
    share = lum / lum.max()
    side = np.clip(np.rint(size * np.maximum(share ** SIZE_POWER, MIN_SIZE)), 16, size)
    return [size] * own + [int(v) if s >= dominant else 0 for v, s in zip(side, share)]


def map_energy(px: np.ndarray) -> np.ndarray:
    """RGB ∫ L dω of an equirectangular map (H×W×C), with exact pixel solid angles."""
    h, w = px.shape[:2]
    return np.einsum("hwc,h->c", px[..., :3].astype(np.float64), solid_angles(h, w)[:, 0])


def downsample(px: np.ndarray, width: int) -> np.ndarray:
    """The map averaged over k×k blocks (solid-angle weighted, so ∫ L dω is kept), k the
    largest power of two with W/k ≥ ``width`` that divides the map."""
    h, w = px.shape[:2]
    k = 1
    while w // (2 * k) >= width and h % (2 * k) == 0 and w % (2 * k) == 0:
        k *= 2
    if k == 1:
        return px.astype(np.float64)
    om = solid_angles(h, w)[:, :, None]
    e = (px.astype(np.float64) * om).reshape(h // k, k, w // k, k, -1).sum((1, 3))
    o = np.repeat(om, w, 1).reshape(h // k, k, w // k, k, 1).sum((1, 3))
    return e / o


def split_peaks(px: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(peaks, rest): the radiance of each pixel above ``threshold`` × the map's mean luminance
    (its colour kept) goes to the peaks, the remainder to the rest; peaks + rest = the map."""
    h, w = px.shape[:2]
    lum = px @ LUMA
    mean = float((lum * solid_angles(h, w)).sum() / (4 * np.pi))
    frac = np.clip(1 - threshold * mean / np.maximum(lum, 1e-30), 0, 1)[..., None]
    peaks = px * frac
    return peaks, px - peaks


def median_cut(energy: np.ndarray, count: int) -> list[tuple[int, int, int, int]]:
    """Debevec's median cut of an H×W energy map (luminance × solid angle) into at most
    ``count`` regions (y0, y1, x0, x1): every round splits each region across its longer side
    (the width measured at the region's mean latitude) where the energy halves; a round stops
    early, splitting the most energetic regions first, once ``count`` is reached."""
    h, w = energy.shape
    regions = [(0, h, 0, w)]
    while len(regions) < count:
        order = sorted(regions, key=lambda r: -energy[r[0]:r[1], r[2]:r[3]].sum())
        grown, done = [], False
        for i, r in enumerate(order):
            parts = None if done else _split(energy, r)
            grown.extend(parts or [r])
            done = done or len(grown) + len(order) - i - 1 >= count
        if len(grown) == len(regions):
            break
        regions = grown
    return regions


def _split(energy: np.ndarray, r: tuple[int, int, int, int]):
    """The two halves of region ``r`` of equal energy, or None when it cannot be split."""
    y0, y1, x0, x1 = r
    h = energy.shape[0]
    lat = np.sin(np.pi * (y0 + y1) / (2 * h))  # cos(latitude) at the region's middle
    along_x = (x1 - x0) * lat >= (y1 - y0) and x1 - x0 > 1
    if not along_x and y1 - y0 < 2:
        return None
    sub = energy[y0:y1, x0:x1]
    c = np.cumsum(sub.sum(0 if along_x else 1))
    if c[-1] <= 0:
        return None
    cut = int(np.clip(np.searchsorted(c, c[-1] / 2) + 1, 1, len(c) - 1))
    if along_x:
        return [(y0, y1, x0, x0 + cut), (y0, y1, x0 + cut, x1)]
    return [(y0, y0 + cut, x0, x1), (y0 + cut, y1, x0, x1)]


def region_light(peaks: np.ndarray, dirs: np.ndarray, om: np.ndarray, r) -> Light | None:
    """The directional light of one median-cut region: its RGB energy / π along its energy
    centroid (the mean direction of its luminance × solid angle), or None when dark."""
    y0, y1, x0, x1 = r
    e = peaks[y0:y1, x0:x1] * om[y0:y1, :, None]
    rgb = e.sum((0, 1))
    lum = e @ LUMA
    c = np.einsum("hw,hwk->k", lum, dirs[y0:y1, x0:x1])
    n = np.linalg.norm(c)
    if not (rgb.max() > 0 and n > 0):
        return None
    intensity = float(rgb.mean()) / np.pi
    return Light(direction=tuple(float(v) for v in c / n),
                 color=tuple(float(v) for v in rgb / (np.pi * intensity)), intensity=intensity)


def environment_lighting(px: np.ndarray, frame: EnvironmentFrame, lights: int, threshold: float,
                         width: int) -> EnvironmentLighting:
    """Median-cut lights of the map's peaks + the SH of the rest, in the world frame."""
    m = downsample(px[..., :3], width)
    h, w = m.shape[:2]
    om = solid_angles(h, w)
    dirs = local_directions(h, w) @ frame.matrix().T
    peaks, rest = split_peaks(m, threshold) if lights else (np.zeros_like(m), m)
    out = []
    if lights and peaks.max() > 0:
        for r in median_cut((peaks @ LUMA) * om, lights):
            light = region_light(peaks, dirs, om, r)
            if light is not None:
                out.append(light)
    sh = np.einsum("hwk,hwc->kc", sh_basis(dirs.reshape(-1, 3)).reshape(h, w, 9), rest * om[..., None])
    return EnvironmentLighting(lights=tuple(out), sh=tuple(tuple(float(v) for v in row) for row in sh))


class EnvironmentLights(Node):
    """An environment map as lights for Render (Paris 2003 Fig. 10-b): the map's bright parts
    (radiance above ``threshold`` × its mean luminance) as at most ``lights`` directional lights
    by Debevec's median cut (each at its region's energy centroid, holding its energy; Render
    casts the shadows of the brightest: its ``environment_shadows``), the rest as an order-2 spherical-harmonic ambient (9 RGB
    coefficients, Ramamoorthi–Hanrahan irradiance; no shadows).  Together they hold the map's
    whole energy (∫ L dω, exact pixel solid angles).  The map is analysed at ``width`` pixels
    (solid-angle-weighted block averages).  ``lights: 0`` puts everything in the ambient.
    Light units: colour × intensity = irradiance / π (a white surface shows the map's radiance
    units).  The frame (LoadEnvironment.frame) turns the map into the world frame.
    """

    version = "1"
    inputs = {"image": In(Image, "equirectangular map (H×2H RGB radiance, LoadEnvironment.image)",
                          finite=True, ge=0),
              "frame": In(EnvironmentFrame, "where the map points (LoadEnvironment.frame)")}
    outputs = {"lighting": Out(EnvironmentLighting, "dominant lights + SH ambient (Render.environment)")}

    class Params(Node.Params):
        lights: int = Field(16, ge=0, le=64, description="most dominant lights (median-cut regions)")
        threshold: float = Field(2.0, ge=0, description="radiance above threshold × the map's mean "
                                                        "luminance goes to the lights, the rest to the ambient")
        width: int = Field(128, ge=8, le=4096, description="analysis width of the map (pixels)")

    def compute(self, image: Image, frame: EnvironmentFrame):
        check_equirect(image.pixels, "image", f"the {image.size_str()} map")
        p = self.params
        return environment_lighting(np.asarray(image.pixels, np.float64), frame, p.lights,
                                    p.threshold, p.width)

    @classmethod
    def examples(cls):
        h = 16
        px = np.full((h, 2 * h, 3), 0.2, np.float32)
        px[3, 20] = (40.0, 35.0, 30.0)
        return [({}, {"image": Image(px), "frame": EnvironmentFrame()}),
                ({"lights": 0}, {"image": Image(px), "frame": EnvironmentFrame()}),
                ({"lights": 3, "threshold": 0.5, "width": 16},
                 {"image": Image(px), "frame": EnvironmentFrame(right=(0, 0, -1), centre=(1, 0, 0))})]
