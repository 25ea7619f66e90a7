"""Melanin and hemoglobin maps from a photo by independent component analysis (Tsumura et
al. 1999, cited in Jimenez 2010 §2.1), and recolouring a photo with a new hemoglobin map.

Beer–Lambert in optical density: −ln RGB = C_m q_m + C_h q_h + s·(1,1,1) + d₀, where q_m, q_h
are the pigments' density vectors (per unit volume fraction), s is shading (a multiplicative
factor equal in all channels) and d₀ a constant.  Projecting the densities onto the plane
orthogonal to (1,1,1) removes the shading exactly; what remains is a 2-D linear mixture of
two independent sources, which FastICA-style rotation of the whitened data separates.  The ICA
components are named (melanin vs hemoglobin) and signed by comparing their mixing directions
with those of the spectral skin model (nodes/jimenez/skinlut.py), and put into volume-fraction
units with that model's Jacobian at the photo's mean skin colour.
"""
from __future__ import annotations

import functools

import numpy as np

from graphkit import Array, BadInput, Field, Image, In, Mask, Node, Out

ONE = np.ones(3) / np.sqrt(3.0)
# orthonormal basis of the plane orthogonal to (1, 1, 1): shading-free density coordinates
PLANE = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, -2.0]]).T / np.array([np.sqrt(2.0), np.sqrt(6.0)])


@functools.lru_cache(maxsize=4)
def model_table(n: int = 33, beta_m: float = 0.61):
    """Spectral-model skin colours on a cube-root grid: (C_m, C_hd, linear RGB) arrays."""
    from .skinlut import lut_axes, reflectance_to_linear_srgb, skin_reflectance

    cm, chd = lut_axes(n, n)
    rgb = reflectance_to_linear_srgb(skin_reflectance(cm[None, :], chd[:, None], beta_m))
    return cm, chd, rgb


def model_jacobian(c_m: float, c_hd: float, beta_m: float = 0.61) -> np.ndarray:
    """d(−ln RGB)/d(C_m, C_hd) of the spectral skin model, (3, 2), by central differences."""
    from .skinlut import reflectance_to_linear_srgb, skin_reflectance

    def dens(a, b):
        return -np.log(np.maximum(reflectance_to_linear_srgb(skin_reflectance(a, b, beta_m)), 1e-6))

    hm = max(1e-4, 0.02 * c_m)
    hh = max(1e-4, 0.02 * c_hd)
    jm = (dens(c_m + hm, c_hd) - dens(max(c_m - hm, 0), c_hd)) / (c_m + hm - max(c_m - hm, 0))
    jh = (dens(c_m, c_hd + hh) - dens(c_m, max(c_hd - hh, 0))) / (c_hd + hh - max(c_hd - hh, 0))
    return np.stack([jm, jh], axis=1)


def model_density(c_m: float, c_hd: float, beta_m: float = 0.61) -> np.ndarray:
    """−ln(linear RGB) of the spectral skin model at (C_m, C_hd)."""
    from .skinlut import reflectance_to_linear_srgb, skin_reflectance

    return -np.log(np.maximum(reflectance_to_linear_srgb(skin_reflectance(c_m, c_hd, beta_m)), 1e-6))


def refine_reference(c: np.ndarray, target_xy: np.ndarray, beta_m: float, steps: int = 8) -> np.ndarray:
    """Gauss–Newton: (C_m, C_hd) whose shading-free model density is nearest ``target_xy``
    (kept inside table 1's ranges)."""
    from .skinlut import CHD_MAX, CM_MAX

    lo, hi = np.array([1e-5, 1e-5]), np.array([CM_MAX, CHD_MAX])
    c = np.clip(np.asarray(c, np.float64), lo, hi)
    for _ in range(steps):
        r = model_density(c[0], c[1], beta_m) @ PLANE - target_xy
        J = PLANE.T @ model_jacobian(c[0], c[1], beta_m)
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        c_new = np.clip(c + step, lo, hi)
        if np.allclose(c_new, c, rtol=1e-6, atol=1e-9):
            break
        c = c_new
    return c


def ica_2d(x: np.ndarray, n_angles: int = 360) -> tuple[np.ndarray, np.ndarray]:
    """ICA of 2-D data (N, 2): returns (sources (N, 2) unit variance, mixing (2, 2)).

    Whitening by PCA, then the rotation maximising the sum of squared excess kurtoses of the
    two outputs (the cumulant contrast of the fixed-point ICA of Hyvärinen & Oja used by
    Tsumura), found by an exhaustive angle search (deterministic, no seed).  (The log-cosh
    negentropy contrast fails for a smooth bimodal melanin pattern mixed with sparse vessels.)
    x ≈ mean + sources @ mixing.T.
    """
    xc = x - x.mean(0)
    cov = np.cov(xc.T)
    ev, E = np.linalg.eigh(cov)
    if ev.min() <= 1e-14 * max(ev.max(), 1e-300):
        raise ValueError("the colour data are (nearly) one-dimensional: two pigments cannot be separated")
    Wh = (E / np.sqrt(ev)).T  # whitening matrix
    z = xc @ Wh.T
    # fourth moments of the whitened data: the contrast is a polynomial in (cos t, sin t)
    z1, z2 = z[:, 0], z[:, 1]
    m40, m31, m22 = (z1 ** 4).mean(), (z1 ** 3 * z2).mean(), (z1 ** 2 * z2 ** 2).mean()
    m13, m04 = (z1 * z2 ** 3).mean(), (z2 ** 4).mean()

    def contrast(t):
        c, s = np.cos(t), np.sin(t)
        k1 = c ** 4 * m40 + 4 * c ** 3 * s * m31 + 6 * c * c * s * s * m22 + 4 * c * s ** 3 * m13 + s ** 4 * m04
        k2 = s ** 4 * m40 - 4 * s ** 3 * c * m31 + 6 * c * c * s * s * m22 - 4 * s * c ** 3 * m13 + c ** 4 * m04
        return (k1 - 3.0) ** 2 + (k2 - 3.0) ** 2

    ts = np.linspace(0, np.pi / 2, 4 * n_angles, endpoint=False)
    vals = contrast(ts)
    t = ts[int(np.argmax(vals))]
    step = ts[1] - ts[0]
    for _ in range(40):  # refine around the best angle
        cand = np.array([t - step, t, t + step])
        t = cand[int(np.argmax(contrast(cand)))]
        step /= 2
    R = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    U = R @ Wh  # unmixing
    return xc @ U.T, np.linalg.inv(U)


def detect_skin(rgb_lin: np.ndarray) -> np.ndarray:
    """Skin-coloured pixels by the classic YCrCb box (Chai & Ngan 1999) on sRGB-encoded values."""
    import cv2

    from nodes.common.color import linear_to_srgb

    srgb = np.clip(linear_to_srgb(np.clip(rgb_lin, 0, 1)), 0, 1)
    ycc = cv2.cvtColor((srgb * 255).astype(np.uint8), cv2.COLOR_RGB2YCrCb)
    cr, cb, y = ycc[..., 1], ycc[..., 2], ycc[..., 0]
    return ((cr >= 133) & (cr <= 173) & (cb >= 77) & (cb <= 127) & (y > 40)).astype(np.float32)


def separate(rgb: np.ndarray, skin: np.ndarray, beta_m: float = 0.61, max_samples: int = 200_000):
    """Core of SkinChromophores: (melanin, hemoglobin, pigments (2, 3), reference (C_m, C_hd))."""
    dens = -np.log(np.clip(rgb.astype(np.float64), 1e-4, None))
    sel = (skin > 0.5) & np.all((rgb > 0.002) & (rgb < 0.98), axis=-1)
    xs = dens[sel] @ PLANE  # shading-free coordinates
    if len(xs) > max_samples:
        xs = xs[:: int(np.ceil(len(xs) / max_samples))]
    src, mix = ica_2d(xs)
    # reference point: the model colour nearest (shading-free) to the mean skin colour
    cm, chd, table = model_table(33, beta_m)
    tdens = -np.log(np.maximum(table, 1e-6)) @ PLANE
    mean_x = xs.mean(0)
    iv, iu = np.unravel_index(np.argmin(((tdens - mean_x) ** 2).sum(-1)), tdens.shape[:2])
    c0 = refine_reference(np.array([cm[iu], chd[iv]]), mean_x, beta_m)
    J = PLANE.T @ model_jacobian(c0[0], c0[1], beta_m)  # (2 plane coords, 2 pigments)
    Jn = J / np.linalg.norm(J, axis=0)
    mixn = mix / np.linalg.norm(mix, axis=0)
    cosm = Jn.T @ mixn  # (pigment, component)
    if abs(cosm[0, 0]) + abs(cosm[1, 1]) >= abs(cosm[0, 1]) + abs(cosm[1, 0]):
        order = [0, 1]
    else:
        order = [1, 0]
    # per-pigment scale: ICA mixing column projected on the model direction, in fraction units
    x_all = dens.reshape(-1, 3) @ PLANE - xs.mean(0)
    U = np.linalg.inv(mix)
    s_all = x_all @ U.T
    maps, vecs = [], []
    for p in range(2):
        j = order[p]
        a = mix[:, j]
        k = float(a @ J[:, p]) / float(J[:, p] @ J[:, p])  # volume fraction per unit source
        if k == 0:
            k = 1e-12
        c = c0[p] + k * s_all[:, j]
        maps.append(c.reshape(rgb.shape[:2]))
        # 3-D density vector per unit fraction (shading-free part from ICA, (1,1,1) part from the model)
        q = PLANE @ (a / k) + ONE * (ONE @ model_jacobian(c0[0], c0[1], beta_m)[:, p])
        vecs.append(q)
    return maps[0], maps[1], np.stack(vecs), c0


class SkinChromophores(Node):
    """Melanin and hemoglobin volume-fraction maps from a photo (Tsumura et al. 1999 ICA,
    as used in Jimenez 2010 §2.1/§3; maps feed §4 and the LUT of §6, eq. 7).

    Optical densities −ln(linear RGB) of skin pixels are projected onto the plane orthogonal to
    (1,1,1), which removes shading; a 2-D ICA separates the two pigments, which are then named
    and scaled to volume fractions with the spectral skin model (β_m = ``melanin_blend``).
    Outputs are unitless volume fractions (C_m and C_hd of table 1, clipped to its ranges),
    zero outside the skin; ``pigments`` is a 2×3 array of density vectors (−ln RGB per unit
    volume fraction; row 0 melanin, row 1 hemoglobin).  Without a ``mask`` the skin is found
    by a YCrCb colour box; with one, that box also removes non-skin pixels inside it (eyes,
    teeth, brows) unless ``colour_check`` is off.
    """

    version = "4"
    inputs = {"image": In(Image, "photo, linear RGB"),
              "mask": In(Mask, "skin mask (optional: detected by colour otherwise)", optional=True,
                         same_size_as="image")}
    outputs = {"melanin": Out(Image, "C_m, volume fraction"),
               "hemoglobin": Out(Image, "C_hd, volume fraction"),
               "pigments": Out(Array, "2×3 density vectors (−ln RGB per unit fraction): melanin, hemoglobin"),
               "skin": Out(Mask, "the skin pixels used")}

    class Params(Node.Params):
        melanin_blend: float = Field(0.61, ge=0, le=1, description="β_m of the model used for naming and scaling")
        min_skin_fraction: float = Field(0.002, ge=0, le=1, description="fewer skin pixels than this share of the photo is an error")
        colour_check: bool = Field(True, description="inside a given mask keep only skin-coloured pixels (drops eyes, teeth, brows)")

    def compute(self, image: Image, mask: Mask | None = None):
        from .skinlut import CHD_MAX, CM_MAX

        px = image.pixels
        if px.shape[2] < 3:
            raise BadInput("image", f"need an RGB photo, got {px.shape[2]} channel(s)")
        rgb = px[:, :, :3]
        if mask is not None:
            skin = (mask.alpha > 0.5).astype(np.float32)
            if self.params.colour_check:
                skin = skin * detect_skin(rgb)
            where = "mask"
        else:
            skin = detect_skin(rgb)
            where = "image"
        usable = (skin > 0.5) & np.all((rgb > 0.002) & (rgb < 0.98), axis=-1)
        need = max(64, int(self.params.min_skin_fraction * skin.size))
        if usable.sum() < need:
            raise BadInput(where, f"no skin found: {int(usable.sum())} usable skin pixels "
                                  f"(need ≥ {need}); give a skin mask or a photo with a face")
        try:
            cm, ch, vecs, _ = separate(rgb, skin, self.params.melanin_blend)
        except ValueError as e:
            raise BadInput(where, f"cannot separate pigments: {e}") from None
        cm = np.clip(cm, 0, CM_MAX) * skin
        ch = np.clip(ch, 0, CHD_MAX) * skin
        return {"melanin": Image(cm.astype(np.float32)), "hemoglobin": Image(ch.astype(np.float32)),
                "pigments": vecs, "skin": Mask(skin)}


class ApplyHemoglobin(Node):
    """Recolour a photo for a new hemoglobin map by Beer–Lambert (Tsumura 1999; Jimenez 2010 §4).

    out = photo · exp(−(H_new − H) · q_h) inside the skin, with q_h the hemoglobin density
    vector (−ln RGB per unit volume fraction, row 1 of SkinChromophores ``pigments``).
    Maps are unitless volume fractions; the photo is linear RGB.
    """

    version = "1"
    inputs = {"image": In(Image, "photo, linear RGB"),
              "pigments": In(Array, "2×3 density vectors from SkinChromophores"),
              "hemoglobin": In(Image, "hemoglobin map of the photo", same_size_as="image", ge=0),
              "new_hemoglobin": In(Image, "desired hemoglobin map", same_size_as="image", ge=0),
              "mask": In(Mask, "skin (optional)", optional=True, same_size_as="image")}
    outputs = {"image": Image}

    def compute(self, image, pigments, hemoglobin, new_hemoglobin, mask=None):
        q = np.asarray(pigments, np.float64)
        if q.shape != (2, 3):
            raise BadInput("pigments", f"expected a 2×3 array of density vectors, got {q.shape}")
        dh = (new_hemoglobin.pixels[:, :, 0] - hemoglobin.pixels[:, :, 0]).astype(np.float64)
        if mask is not None:
            dh = dh * mask.alpha
        px = image.pixels.astype(np.float64).copy()
        px[:, :, :3] *= np.exp(-dh[..., None] * q[1])
        return Image(px.astype(np.float32), image.colorspace)
