"""Screen-space subsurface scattering with the sum-of-Gaussians skin profile.

The diffusion profile of skin is approximated by d'Eon, Luebke & Enderton 2007 (*Efficient
rendering of human skin*, EGSR; GPU Gems 3 ch. 14, table 14-1) as a sum of six Gaussians

    R(r) = Σ_i  w_i · G(v_i, r),     G(v, r) = exp(-r² / 2v) / (2π v),

with variances ``v_i`` in **mm²** (so each Gaussian has a standard deviation √v_i mm on the skin
surface) and RGB weights ``w_i`` that sum to one per channel (energy conserving).  Jimenez et
al. 2009/2010 (Jimenez 2010 §6) apply this blur in screen space, to the *diffuse irradiance
only* (post-scatter texturing: the albedo is multiplied in afterwards), and adapt the kernel
width per pixel from the depth gradient so that a kernel covers the same surface distance on
foreshortened skin and stops at silhouettes.

Here each Gaussian is applied separably (y then x).  Where σ is the same at every pixel the
blur is scipy's ``gaussian_filter1d``; otherwise a per-pixel gather of the same truncated,
normalised kernel (float32 for a spatially varying σ).  At a pixel the standard deviation in
pixels along an image axis is

    σ_px = √v_i / ℓ,     ℓ = √(mm_per_pixel² + (∂depth/∂axis)²)   [mm per pixel step on the surface]

where ``depth`` is in mm and its derivative is taken by central differences (pixels).  On a flat
depth (or without depth) and a scalar ``mm_per_pixel``, the result is exactly the weighted sum
of ``scipy.ndimage.gaussian_filter`` results (same 4σ truncation, same ``reflect`` boundary).

Public, stable API (also used by the Huang 2013 cosmetics nodes)::

    SKIN_PROFILE: tuple[(variance_mm2, (w_r, w_g, w_b)), ...]
    sss_blur(irradiance, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None) -> ndarray
"""
from __future__ import annotations

import numpy as np

#: d'Eon et al. 2007 six-Gaussian fit of the three-layer skin diffusion profile
#: (GPU Gems 3, ch. 14, table 14-1): (variance in mm², RGB weight).
SKIN_PROFILE: tuple[tuple[float, tuple[float, float, float]], ...] = (
    (0.0064, (0.233, 0.455, 0.649)),
    (0.0484, (0.100, 0.336, 0.344)),
    (0.187, (0.118, 0.198, 0.000)),
    (0.567, (0.113, 0.007, 0.007)),
    (1.99, (0.358, 0.004, 0.000)),
    (7.41, (0.078, 0.000, 0.000)),
)

TRUNCATE = 4.0  # kernel radius in standard deviations (as scipy.ndimage.gaussian_filter)


def _pixel_step_mm(mm_per_pixel, depth, shape) -> tuple[np.ndarray, np.ndarray]:
    """Surface length (mm) covered by one pixel step along x and along y, per pixel."""
    h, w = shape
    mpp = np.broadcast_to(np.asarray(mm_per_pixel, dtype=np.float64), (h, w))
    if depth is None:
        return mpp, mpp
    d = np.asarray(depth, dtype=np.float64)
    gy, gx = (np.gradient(d) if min(h, w) > 1 else (np.zeros_like(d), np.zeros_like(d)))
    return np.sqrt(mpp ** 2 + gx ** 2), np.sqrt(mpp ** 2 + gy ** 2)


def _blur_axis_uniform(img: np.ndarray, sigma: float, axis: int, valid: np.ndarray | None) -> np.ndarray:
    """Same as :func:`_blur_axis` for a σ that is the same at every pixel (scipy, O(r) taps)."""
    from scipy.ndimage import gaussian_filter1d

    if sigma <= 0 or int(TRUNCATE * sigma + 0.5) == 0:
        return img.copy()
    if valid is None:
        return gaussian_filter1d(img, sigma, axis=axis, mode="reflect", truncate=TRUNCATE)
    num = gaussian_filter1d(img * valid[..., None], sigma, axis=axis, mode="reflect", truncate=TRUNCATE)
    den = gaussian_filter1d(valid, sigma, axis=axis, mode="reflect", truncate=TRUNCATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den[..., None]
    return np.where(den[..., None] > 1e-12, out, img)


def _blur_axis(img: np.ndarray, sigma: np.ndarray, axis: int, valid: np.ndarray | None) -> np.ndarray:
    """Gaussian blur along ``axis`` (0 = y, 1 = x) with a per-pixel σ (pixels).

    Gather form: out(x) = Σ_k g_x(k) img(x+k) / Σ_k g_x(k), g_x(k) = exp(-k²/2σ(x)²) for
    |k| ≤ int(4σ(x) + 0.5), boundary mirrored like scipy's ``reflect``; taps where ``valid`` is
    0 are left out (and the weights renormalised).
    """
    rmap = np.floor(TRUNCATE * sigma + 0.5).astype(np.int64)
    R = int(rmap.max()) if rmap.size else 0
    if R == 0:
        return img.copy()
    dt = img.dtype
    pad = [(0, 0)] * 3
    pad[axis] = (R, R)
    src = np.pad(img, pad, mode="symmetric")
    vsrc = None if valid is None else np.pad(valid.astype(dt), pad[:2], mode="symmetric")
    with np.errstate(divide="ignore"):
        inv = np.where(sigma > 0, 0.5 / np.maximum(sigma, 1e-30) ** 2, 0.0).astype(dt)
    n = img.shape[axis]

    def tap(k):
        sl = slice(R + k, R + k + n)
        if axis == 0:
            return src[sl], (None if vsrc is None else vsrc[sl])
        return src[:, sl], (None if vsrc is None else vsrc[:, sl])

    # k = 0, then the pairs ±k share one weight; w_k = exp(−k²a) by the recurrence
    # w_k = w_{k−1}·g_k, g_k = g_{k−1}·exp(−2a) (two products per tap instead of an exp)
    s0, v0 = tap(0)
    if v0 is None:
        acc = s0.astype(dt, copy=True)
        wsum = np.ones(img.shape[:2], dt)
    else:
        acc = v0[..., None] * s0
        wsum = v0.astype(dt, copy=True)
    e2 = np.exp(-2.0 * inv)
    g = np.exp(-inv)  # g_1
    w = np.ones(img.shape[:2], dt)
    for k in range(1, R + 1):
        w *= g
        g *= e2
        wk = np.where(k <= rmap, w, 0).astype(dt, copy=False)
        sp, vp = tap(k)
        sm, vm = tap(-k)
        if vp is None:
            acc += wk[..., None] * (sp + sm)
            wsum += 2 * wk
        else:
            wp, wm = wk * vp, wk * vm
            acc += wp[..., None] * sp + wm[..., None] * sm
            wsum += wp + wm
    with np.errstate(invalid="ignore", divide="ignore"):
        out = acc / wsum[..., None]
    return np.where(wsum[..., None] > 0, out, img)


def _blur(img, sigma, axis, valid):
    flat = sigma.ravel()
    if flat.size and np.all(flat == flat[0]):
        return _blur_axis_uniform(img, float(flat[0]), axis, valid)
    return _blur_axis(img, sigma, axis, valid)


def sss_blur(irradiance: np.ndarray, mm_per_pixel: float | np.ndarray, depth: np.ndarray | None = None,
             profile=SKIN_PROFILE, mask: np.ndarray | None = None) -> np.ndarray:
    """Screen-space sum-of-Gaussians subsurface scattering of a diffuse irradiance image.

    irradiance   (H, W, 3) linear diffuse lighting (no albedo: post-scatter texturing,
                 Jimenez 2010 §6); other channel counts are blurred with the first weights.
    mm_per_pixel lateral size of a pixel on the skin in **mm** (scalar or (H, W) array, e.g.
                 depth / focal length for a pinhole camera).
    depth        optional (H, W) camera depth in **mm**; its gradient widens the pixel step
                 (foreshortening) and so narrows the kernel, stopping blur at silhouettes.
    profile      sequence of (variance in **mm²**, RGB weight) — default d'Eon 2007 skin.
    mask         optional (H, W) skin mask in [0, 1]; pixels with mask ≤ 0.5 neither scatter
                 light into skin nor are changed.
    Returns float32 (H, W, C).
    """
    img = np.asarray(irradiance, dtype=np.float32)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[:, :, None]
    if img.ndim != 3:
        raise ValueError(f"irradiance must be H×W×C, got shape {img.shape}")
    h, w, c = img.shape
    mpp = np.asarray(mm_per_pixel, dtype=np.float64)
    if mpp.ndim not in (0, 2) or (mpp.ndim == 2 and mpp.shape != (h, w)):
        raise ValueError(f"mm_per_pixel must be a scalar or {(h, w)}, got shape {mpp.shape}")
    if not np.all(mpp > 0):
        raise ValueError("mm_per_pixel must be > 0 everywhere")
    if depth is not None and np.shape(depth) != (h, w):
        raise ValueError(f"depth must be {(h, w)}, got {np.shape(depth)}")
    valid = None
    if mask is not None:
        if np.shape(mask) != (h, w):
            raise ValueError(f"mask must be {(h, w)}, got {np.shape(mask)}")
        valid = (np.asarray(mask) > 0.5).astype(np.float64)
    step_x, step_y = _pixel_step_mm(mpp, depth, (h, w))
    out = np.zeros(img.shape, np.float64)
    for var, rgb in profile:
        wts = np.zeros(c)
        wts[: min(c, 3)] = np.asarray(rgb, np.float64)[: min(c, 3)]
        if c > 3:
            wts[3:] = rgb[-1]
        if not np.any(wts):
            continue
        sd = float(np.sqrt(var))
        b = _blur(img, sd / step_y, 0, valid)
        b = _blur(b, sd / step_x, 1, valid)
        out += b * wts
    if valid is not None:
        out = np.where(valid[..., None] > 0, out, img)
    out = out.astype(np.float32)
    return out[:, :, 0] if squeeze else out


__all__ = ["SKIN_PROFILE", "sss_blur"]
