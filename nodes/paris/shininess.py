"""ShininessFromSaturation — the Phong exponent from the size of the highlight (Paris 2003 §4.2)."""
from __future__ import annotations

from typing import Literal

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out, Scalar

from . import sphere
from .checks import rgb_pixels, unit_direction


def _light_dir_camera(light: Light, camera: Camera | None = None) -> np.ndarray:
    """The light's direction (towards the light) in the camera frame of the map / photo: the
    light is in the world frame, and ``camera`` (the photo camera) turns it into its own
    frame; without a camera the world is taken as the camera frame."""
    d = np.asarray(light.direction, np.float64)
    return d if camera is None else camera.dir_to_camera(d)


class ShininessFromSaturation(Node):
    """Phong exponent s from the highlight's saturation profile (Paris 2003 §4.2, eqs. (1)–(3)).

    The highlight sits at the normal halfway between the light and the view direction.  Along
    the angle α from it, the angle of the fastest saturation change, α_sat^max, gives, with
    ζ = sin α_sat^max, eq. (3)

        s = (4ζ⁴ − 2ζ² − 1 − √(−16ζ⁶ + 8ζ⁴ + 1)) / (8ζ²(ζ − 1)(ζ + 1)),

    the inflection of ρ(α) = cos^s(2α)/cos(α), eq. (2), solved for s.  Colours are first
    divided by the light's colour (so the flash is white).  ``measure``:

    * ``"inverse"`` (default) — the fastest *decrease* of 1/S, where S = (max − min)/max is the
      HSV saturation.  A pixel mixing skin colour C and white flash, c = cos α·(C + ρ·(1,1,1)),
      has 1/S = (C_max + ρ)/(C_max − C_min): affine in ρ, so its fastest change is exactly the
      largest change of ρ, eq. (1), whatever the skin colour and the specular intensity.
    * ``"hsv"`` — the fastest increase of S itself, as the paper words it (S is a monotone but
      non-linear function of ρ, so this shifts α_sat with the specular/diffuse ratio).

    **Where the profile comes from.**

    * *The photo's own pixels* (``image``, ``mesh``, ``camera``, ``skin`` all connected: the
      inputs of ReflectanceMap): every skin pixel on the mesh is a sample (its interpolated
      normal and colour, camera frame) at its angle α from its own highlight normal (halfway
      between the light and that pixel's view direction); the colour against α is a local
      linear regression of the samples with a Gaussian kernel (σ ≈ α_sat/8, two passes;
      ``kernel_deg``) and the fastest change is found on that profile.  This does not depend
      on any map's clusters or smoothing: on POV-Ray spheres through ReflectanceMap →
      ShininessFromSaturation, s = 5…150 come out within −3…+2 %, with or without a highlight
      clipped in red (tests/oracles/test_paris_shininess_povray.py).
    * *The map* (``reflectance`` only): the profile is read from the map by cubic
      interpolation along the great circle towards the image-plane left and right (the paper's
      choice), every ``step_deg``.  A map that averages samples (ReflectanceMap's clusters
      and distance-weighted interpolation) widens the highlight, so s comes out wrong
      (−4 … −63 % at s = 5…150 with ReflectanceMap's defaults on POV-Ray spheres, 512 px);
      connect the photo inputs for an unbiased exponent.

    **Clipped pixels.**  A channel is clipped at ``clip_level`` (default: found — a channel's
    maximum reached by several pixels spread over more than a spot on the sphere: the flat top
    of a clipped photo or map).  A pixel clipped in one or two channels is restored from its
    unclipped ones with the paper's model (the specular adds the same amount to every channel
    after white balance, §4.2): c_k = c_u + (n·l)·(C_k − C_u), the channel differences C_k − C_u
    the median of the unclipped samples' (c_k − c_u)/(n·l).  Pixels clipped in all three
    channels are left out; when the fastest change is not clear of them (by ``min_clear_deg``
    and two profile steps), the node refuses (exit 2) with the clipped share, and it refuses a
    photo whose diffuse skin clips too (≥ 2 % of the samples beyond ⅔ of ``max_angle_deg``).
    In a map, only an exact flat top is seen (a map sampled from the photo at its normals); a
    map that averages samples (ReflectanceMap) blurs the flat top away, and a highlight clipped
    in red then gives exponents 2–4× too high — one more reason to connect the photo.

    Inputs: ``light`` in the world frame, brought into the photo camera's frame (that of the
    map and of the photo's normals) with ``camera`` (see ``_light_dir_camera``; without a
    camera the world is taken as the camera frame, as for a map alone).
    Output: s (unitless).  Units: angles in degrees.
    """

    version = "3"  # 3: the light is in the world frame (turned into the camera frame with `camera`)
    inputs = {"reflectance": In(Image, "reflectance map on the Gaussian sphere (nodes.paris.sphere layout)",
                                optional=True),
              "light": In(Light, "the flash of the photo (direction towards the light, world frame: "
                                 "ProbeLight.light)"),
              "image": In(Image, "the photo (linear RGB): with mesh, camera and skin, the profile is read "
                                 "from its pixels instead of the map", optional=True),
              "mesh": In(Mesh, "face mesh registered to the photo (with image)", optional=True, finite=True),
              "camera": In(Camera, "the photo camera: brings the world-frame light into the map's / photo's "
                                   "camera frame (needed with image)", optional=True, same_size_as="image"),
              "skin": In(Mask, "skin pixels of the photo (with image)", optional=True, same_size_as="image")}
    outputs = {"shininess": Out(Scalar, "Phong exponent s (unitless)")}

    class Params(Node.Params):
        measure: Literal["inverse", "hsv"] = Field("inverse", description="saturation measure (see the docstring)")
        max_angle_deg: float = Field(40.0, gt=1, le=44, description="how far from the highlight to look (degrees)")
        step_deg: float | None = Field(None, gt=0, description="map path: profile sampling step (degrees); default: map resolution / 8")
        smooth_deg: float = Field(0.0, ge=0, description="map path: Gaussian smoothing of the profile before differentiating (degrees)")
        kernel_deg: float | None = Field(None, gt=0, description="photo path: σ of the profile's Gaussian kernel (degrees); default: about α_sat / 8 (two passes)")
        min_kernel_samples: float = Field(20.0, gt=0, description="photo path: profile points with fewer samples under the kernel are dropped")
        skin_threshold: float = Field(0.5, ge=0, le=1, description="photo path: mask value counted as skin")
        clip_level: float | None = Field(None, gt=0, description="value at which the camera clips (every channel); default: found from the data")
        min_clear_deg: float = Field(0.1, ge=0, description="the fastest change must lie this far beyond the fully clipped core (and a few bins)")

    def compute(self, light: Light, reflectance: Image | None = None, image: Image | None = None,
                mesh=None, camera: Camera | None = None, skin: Mask | None = None):
        ldir = _light_dir_camera(light, camera)
        color = np.asarray(light.color, np.float64)
        if not (color > 0).all():
            raise BadInput("light", f"the light colour {tuple(color)} must be positive in every channel")
        white = color / color.max()
        photo = {"image": image, "mesh": mesh, "skin": skin}
        given = [k for k, v in photo.items() if v is not None]
        if given and (len(given) < 3 or camera is None):
            missing = [k for k, v in {"image": image, "mesh": mesh, "camera": camera, "skin": skin}.items()
                       if v is None]
            raise BadInput(missing[0], f"the photo path needs image, mesh, camera and skin together; "
                                       f"{', '.join(given)} given, {', '.join(missing)} missing")
        h = highlight_normal(ldir)
        if h[2] > -np.cos(np.radians(80)):
            raise BadInput("light", "the highlight is at the rim of the visible hemisphere or beyond: "
                                    "the light is too far from the camera (or behind the face)")
        if given:
            return self._from_photo(image, mesh, camera, skin, ldir, white)
        if reflectance is None:
            raise BadInput("reflectance", "connect the reflectance map, or the photo with its mesh, camera and skin")
        return self._from_map(reflectance, ldir, white, h)

    # -- the map (the paper's path) -------------------------------------------------------------
    def _from_map(self, reflectance: Image, ldir, white, h):
        p = self.params
        rmap = np.asarray(reflectance.pixels, np.float64)
        rows, cols, ch = rmap.shape
        if cols != 2 * rows or ch < 3:
            raise BadInput("reflectance", f"a reflectance map is rows × 2·rows × 3 (θ × φ × RGB), got "
                                          f"{cols}×{rows}×{ch}")
        if not np.isfinite(rmap).all():
            raise BadInput("reflectance", "the map holds NaN or Inf values")
        res = 180.0 / rows
        rmap = rmap[..., :3]
        n = sphere.pixel_normals(res)
        visible = n[..., 2] < 0
        levels = clip_levels(rmap[visible], p.clip_level, min_pixels=3, normals=n[visible], min_spread_deg=1.5 * res)
        # pixels near the flat top: interpolation in the map mixes clipped values with their
        # neighbours, so a margin of 2 % below the clip level counts as clipped
        clipped = np.isfinite(levels) & (rmap >= 0.98 * levels)
        wb = rmap / white
        full = np.zeros(rmap.shape[:2], bool)
        if clipped.any():
            a_map = np.degrees(np.arccos(np.clip(n[visible] @ h, -1, 1)))
            _refuse_clipped_diffuse(a_map, clipped[visible], p.max_angle_deg, "reflectance")
            flat = wb.reshape(-1, 3)
            ok, fully = restore_clipped(flat, clipped.reshape(-1, 3), (n.reshape(-1, 3) @ ldir) / np.linalg.norm(ldir),
                                        visible.reshape(-1), "reflectance")
            wb = ok.reshape(rmap.shape)
            full = fully.reshape(rmap.shape[:2])
        step = p.step_deg or res / 8
        alphas = np.arange(0.0, p.max_angle_deg + step / 2, step)
        sides = []
        for sign in (+1, -1):
            nn = great_circle(h, sign, np.radians(alphas))
            rgb = sample_cubic(wb, nn, res)
            lo = 0.0
            if full.any():
                hit = sample_cubic(full[..., None].astype(np.float64), nn, res)[:, 0] > 0.01
                lo = float(alphas[hit].max()) + res if hit.any() else 0.0
            sides.append(_fastest_clear(alphas, rgb, p.measure, p.smooth_deg / step, lo, p.min_clear_deg))
        share = float(clipped.any(-1)[visible].mean())
        for a in sides:
            if isinstance(a, str):
                raise BadInput("reflectance", a + f" ({100 * share:.2f}% of the map's visible pixels clipped)")
        if any(a is None for a in sides):
            raise BadInput("reflectance", "no highlight: the saturation does not change around the "
                                          "highlight direction given by the light")
        return _exponent(0.5 * (sides[0] + sides[1]), "reflectance")

    # -- the photo's own pixels ---------------------------------------------------------------
    def _from_photo(self, image, mesh, camera, skin, ldir, white):
        from .render import skin_surface

        p = self.params
        px = rgb_pixels(image, "image")
        s, use = skin_surface(mesh, camera, skin, p.skin_threshold, fewest=50)
        R = camera.pose[:3, :3]
        normals = s.normals[use] @ R.T
        view = s.view[use] @ R.T
        cols = px[s.coverage][use]
        levels = clip_levels(cols, p.clip_level, min_pixels=3, normals=normals, min_spread_deg=0.2)
        clipped = cols >= (1 - 1e-4) * levels
        l = ldir / np.linalg.norm(ldir)
        hn = l[None, :] + view
        hn /= np.linalg.norm(hn, axis=1, keepdims=True)
        alpha = np.degrees(np.arccos(np.clip(np.sum(normals * hn, 1), -1, 1)))
        near = alpha <= p.max_angle_deg
        if near.sum() < 50:
            raise BadInput("skin", f"only {int(near.sum())} skin samples within {p.max_angle_deg:.0f}° of the "
                                   "highlight normal: the skin does not face the flash")
        wb = cols / white
        full = np.zeros(len(cols), bool)
        if clipped.any():
            _refuse_clipped_diffuse(alpha[near], clipped[near], p.max_angle_deg, "image")
            wb, full = restore_clipped(wb, clipped, normals @ l, near)
        a, wb, full, cl = alpha[near], wb[near], full[near], clipped[near].any(1)
        lo = float(np.percentile(a[full], 99)) if full.sum() >= 3 else (float(a[full].max()) if full.any() else 0.0)
        ok = ~full
        a_sat = None
        passes = [p.kernel_deg] if p.kernel_deg else [0.5, None]
        for sig in passes:
            if sig is None:   # second pass: a kernel of about α_sat / 8
                sig = float(np.clip(a_sat / 8.0, 0.05, 1.0))
            alphas, rgb, _ = smooth_profile(a[ok], wb[ok], sig, p.max_angle_deg, p.min_kernel_samples)
            if len(alphas) < 8:
                raise BadInput("skin", "too few skin samples around the highlight to measure its profile")
            res = _fastest_clear(alphas, rgb, p.measure, 0.0, lo, p.min_clear_deg)
            if isinstance(res, str):
                share = 100 * float(cl.mean())
                hl = a <= 2 * max(lo, 1e-9) + 2 * sig
                raise BadInput("image", res + f" (clipped: {100 * float(cl[hl].mean()):.0f}% of the samples within "
                                        f"{2 * lo + 2 * sig:.1f}° of the highlight, {share:.2f}% of the skin "
                                        f"samples within {p.max_angle_deg:.0f}°)")
            if res is None:
                raise BadInput("image", "no highlight: the saturation does not change around the highlight "
                                        "direction given by the light")
            a_sat = res
        return _exponent(a_sat, "image")


def _exponent(a_sat: float, port: str) -> float:
    s = shininess_from_angle(np.radians(a_sat))
    if not np.isfinite(s) or s <= 0:
        raise BadInput(port, f"the fastest saturation change is {a_sat:.1f}° from the highlight, which no "
                             "Phong exponent gives (eq. 3)")
    return float(s)


def clip_levels(colours: np.ndarray, given: float | None = None, min_pixels: int = 3,
                normals: np.ndarray | None = None, min_spread_deg: float = 0.0) -> np.ndarray:
    """Per-channel clip level of N×3 colours: ``given`` for every channel, or a channel's maximum
    when at least ``min_pixels`` values reach it (within 1e-4: the flat top of a clipped photo)
    and, with ``normals`` (N×3), when those values spread over more than ``min_spread_deg`` on
    the sphere (a smooth, unclipped peak is flat only over a tiny spot; a clipped one over the
    core of the highlight); +inf for a channel that does not clip."""
    if given is not None:
        return np.full(3, float(given))
    out = np.full(3, np.inf)
    for c in range(3):
        m = float(colours[:, c].max())
        top = colours[:, c] >= (1 - 1e-4) * m
        if m <= 0 or int(top.sum()) < min_pixels:
            continue
        if normals is not None:
            mean = normals[top].mean(0)
            mean /= max(np.linalg.norm(mean), 1e-12)
            spread = np.degrees(np.arccos(np.clip(normals[top] @ mean, -1, 1))).max()
            if spread <= min_spread_deg:
                continue
        out[c] = m
    return out


def _refuse_clipped_diffuse(alpha, clipped, max_angle, port):
    """Clipping must be the highlight's: when ≥ 2 % of the samples in the outer third of the
    analysed range (α > ⅔·max_angle, beyond any highlight of s ≳ 3) are clipped in some
    channel, the diffuse skin itself clips — the photo is over-exposed and no channel can be
    restored from the others."""
    outer = alpha > (2.0 / 3.0) * max_angle
    if outer.sum() >= 20:
        share = float(clipped[outer].any(1).mean())
        if share >= 0.02:
            raise BadInput(port, f"over-exposed: {100 * share:.0f}% of the skin samples more than "
                                 f"{2 * max_angle / 3:.0f}° from the highlight are clipped (not only the "
                                 "highlight: the diffuse skin itself), so the clipped pixels cannot be modelled; "
                                 "lower the exposure")


def restore_clipped(colours, clipped, ndotl, use, port="image"):
    """Colours (N×3, white-balanced) with channels clipped in one or two channels restored from
    the unclipped ones (white specular: c_k − c_u = (n·l)(C_k − C_u), the differences the median
    over the unclipped samples in ``use``) → (restored colours, clipped in all channels)."""
    out = np.array(colours, np.float64, copy=True)
    full = clipped.all(1)
    clean = use & ~clipped.any(1) & (ndotl > 0.05)
    if clean.sum() < 10:
        raise BadInput(port, "too few unclipped samples to model the clipped ones")
    nl = np.maximum(ndotl, 0.05)
    diff = np.array([[np.median((colours[clean, k] - colours[clean, u]) / nl[clean]) for u in range(3)]
                     for k in range(3)])
    part = clipped.any(1) & ~full
    for i in np.nonzero(part)[0]:
        us = np.nonzero(~clipped[i])[0]
        for k in np.nonzero(clipped[i])[0]:
            out[i, k] = np.mean([colours[i, u] + nl[i] * diff[k, u] for u in us])
    return out, full


def smooth_profile(alpha, rgb, sigma_deg, max_angle, min_weight=20.0):
    """Colour against α (degrees) by local linear regression with a Gaussian kernel of
    ``sigma_deg`` (from bin sums on a grid of σ/4, convolved with the kernel) → (α grid, colours,
    kernel weight ≈ samples within ±σ); grid points with less than ``min_weight`` are dropped."""
    b = sigma_deg / 4.0
    nb = int(np.ceil(max_angle / b)) + 1
    idx = np.clip((alpha / b).astype(np.int64), 0, nb - 1)
    n = np.bincount(idx, minlength=nb).astype(np.float64)
    sa = np.bincount(idx, alpha, nb)
    saa = np.bincount(idx, alpha * alpha, nb)
    sc = np.stack([np.bincount(idx, rgb[:, k], nb) for k in range(3)], 1)
    sac = np.stack([np.bincount(idx, alpha * rgb[:, k], nb) for k in range(3)], 1)
    j = np.arange(-16, 17)
    g = np.exp(-0.5 * (j * b / sigma_deg) ** 2)
    conv = lambda v: np.convolve(v, g, mode="same")  # noqa: E731
    grid = (np.arange(nb) + 0.5) * b
    S0, Sa, Saa = conv(n), conv(sa), conv(saa)
    S1 = Sa - grid * S0
    S2 = Saa - 2 * grid * Sa + grid * grid * S0
    out = np.zeros((nb, 3))
    for k in range(3):
        T0 = conv(sc[:, k])
        T1 = conv(sac[:, k]) - grid * T0
        den = S0 * S2 - S1 * S1
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, k] = np.where(den > 1e-12 * np.maximum(S0, 1) ** 2, (S2 * T0 - S1 * T1) / den, T0 / np.maximum(S0, 1e-12))
    keep = (S0 >= min_weight) & (grid <= max_angle)
    return grid[keep], out[keep], S0[keep]


def _fastest_clear(alphas, rgb, measure, smooth, lo, min_clear):
    """fastest_change on the part of the profile beyond the fully clipped core (α > lo); a str
    (the reason) when the fastest change is not clear of it."""
    keep = alphas > lo
    if lo > 0 and keep.sum() < 8:
        return f"the highlight is clipped in all channels out to {lo:.1f}° from its centre: too little of it is left"
    a = fastest_change(alphas[keep], rgb[keep], measure, smooth)
    if a is None or lo <= 0:
        return a
    step = float(np.median(np.diff(alphas[keep])))
    if a < lo + max(min_clear, 2 * step):
        return (f"the highlight is clipped in all channels out to {lo:.2f}° from its centre and its fastest "
                f"saturation change ({a:.2f}°) is not clear of that core: too little of the highlight is left")
    return a


def shininess_from_angle(alpha: float | np.ndarray) -> float | np.ndarray:
    """Eq. (3): Phong exponent s whose ρ(α) = cos^s(2α)/cos α has its inflection at α (radians)."""
    z = np.sin(alpha)
    z2 = z * z
    with np.errstate(invalid="ignore", divide="ignore"):
        return (4 * z2 * z2 - 2 * z2 - 1 - np.sqrt(-16 * z2 ** 3 + 8 * z2 * z2 + 1)) / (8 * z2 * (z - 1) * (z + 1))


def highlight_normal(direction) -> np.ndarray:
    """Normal of the highlight: halfway between the light and the camera (−z), unit."""
    hv = unit_direction(direction, "light") + np.array([0.0, 0.0, -1.0])
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
