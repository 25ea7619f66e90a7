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

Here each Gaussian is applied separably (y then x), in float32, to the colour channels whose
weight is not zero, with ``cv2.filter2D`` and scipy's truncated, normalised kernel and
``reflect`` boundary (:func:`gaussian_kernel`, :func:`_blur_1d`).  Where σ varies per pixel, the kernel at a pixel
is the Gaussian of that pixel's σ (the gather :func:`_blur_axis`, kept as the reference); it is
evaluated as uniform blurs at σ levels ≤ 2% apart (at most 32 per axis), each pixel's kernel
interpolated linearly in σ between the two levels around its σ: exact on the levels (the
extremes, two-valued footprints, σ < 1/8 px), ~1e-4 of the signal elsewhere (measured against
the gather in tests/test_jimenez_nodes.py).  At a pixel the standard deviation in
pixels along an image axis is

    σ_px = √v_i / ℓ,     ℓ = √(mm_per_pixel² + (∂depth/∂axis)²)   [mm per pixel step on the surface]

where ``depth`` is in mm and its derivative is taken by central differences (pixels).  On a flat
depth (or without depth) and a scalar ``mm_per_pixel``, the result is the weighted sum of
``scipy.ndimage.gaussian_filter`` results (same 4σ truncation, same ``reflect`` boundary; equal
to float32 round-off, ~1e-7 relative).

Public, stable API (also used by the Huang 2013 cosmetics nodes)::

    SKIN_PROFILE: tuple[(variance_mm2, (w_r, w_g, w_b)), ...]
    sss_blur(irradiance, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None) -> ndarray
    Scatter(shape, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None, crop=False)(irradiance)
"""
from __future__ import annotations

import functools

import numpy as np

from .parallel import run_tasks

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
#: ratio between successive σ levels of a per-pixel σ (depth gradient, pixel footprint map)
LEVEL_RATIO = 1.02
MAX_LEVELS = 32


def _pixel_step_mm(mm_per_pixel, depth, shape) -> tuple[np.ndarray, np.ndarray]:
    """Surface length (mm) covered by one pixel step along x and along y, per pixel."""
    h, w = shape
    mpp = np.broadcast_to(np.asarray(mm_per_pixel, dtype=np.float64), (h, w))
    if depth is None:
        return mpp, mpp
    d = np.asarray(depth, dtype=np.float64)
    gy, gx = (np.gradient(d) if min(h, w) > 1 else (np.zeros_like(d), np.zeros_like(d)))
    return np.sqrt(mpp ** 2 + gx ** 2), np.sqrt(mpp ** 2 + gy ** 2)


@functools.lru_cache(maxsize=64)
def gaussian_kernel(sigma: float) -> np.ndarray:
    """scipy.ndimage's Gaussian: taps exp(−k²/2σ²) for |k| ≤ int(4σ + 0.5), normalised to
    sum 1 (float32, read-only)."""
    R = int(TRUNCATE * sigma + 0.5)
    k = np.arange(-R, R + 1, dtype=np.float64)
    g = np.exp(-0.5 * k * k / (sigma * sigma)) if sigma > 0 else (k == 0).astype(np.float64)
    g = (g / g.sum()).astype(np.float32)
    g.setflags(write=False)
    return g


def _blur_1d(plane: np.ndarray, sigma: float, axis: int) -> np.ndarray:
    """Gaussian blur of a float32 (H, W) plane along ``axis`` (0 = y, 1 = x) with one σ
    (pixels): ``cv2.filter2D`` with the :func:`gaussian_kernel` taps as a column or row and
    BORDER_REFLECT (= scipy's ``reflect``, also for kernels longer than the image).  (Two 1-D
    ``filter2D`` passes take ~0.6× the time of one ``sepFilter2D`` at these sizes.)"""
    import cv2

    k = gaussian_kernel(sigma)
    if k.size == 1:
        return plane
    return cv2.filter2D(plane, -1, k.reshape((-1, 1) if axis == 0 else (1, -1)), borderType=cv2.BORDER_REFLECT)


class _Levels:
    """Levels for a per-pixel σ map, and per pixel the lower level j and the fraction t ∈ [0, 1]
    towards level j + 1.  Level 0 is σ = 0 (the identity: every σ < 1/8 px has a one-tap
    kernel, so those pixels are exact); then σ_lo … σ_max in geometric steps (both ends exact)
    of LEVEL_RATIO or, where more than MAX_LEVELS levels would be needed, wider.  ``scaled``
    gives the levels of k·σ with the same j, t (the six Gaussians share one plan per axis)."""

    SMALL = 0.5 / TRUNCATE  # int(4σ + 0.5) = 0 below it

    def __init__(self, sigma: np.ndarray):
        lo, hi = float(sigma.min()), float(sigma.max())
        self.sigma, self.lo = sigma, lo
        self.scale = 1.0  # the per-pixel σ (px) is scale · sigma (see scaled)
        self._w = {}  # level → weights (shared by the scaled copies)
        self.exact_identity = lo >= self.SMALL  # no identity pixels to separate
        lo = max(lo, self.SMALL)
        if hi < self.SMALL:
            self.levels = np.zeros(1)
            j, t = np.zeros(sigma.shape, np.int16), np.zeros(sigma.shape, np.float32)
        else:
            n = 1 if hi <= lo else min(int(np.ceil(np.log(hi / lo) / np.log(LEVEL_RATIO))) + 1, MAX_LEVELS)
            geo = np.array([lo]) if n == 1 else lo * (hi / lo) ** (np.arange(n) / (n - 1))
            geo[-1] = hi
            self.levels = np.concatenate([[0.0], geo])
            if n == 1:
                j, t = np.ones(sigma.shape, np.int16), np.zeros(sigma.shape, np.float32)
            else:
                j = np.clip(np.searchsorted(geo, sigma, side="right"), 1, n - 1)  # geo[j−1] ≤ σ < geo[j]
                t = np.clip((sigma - geo[j - 1]) / (geo[j] - geo[j - 1]), 0.0, 1.0).astype(np.float32)
                j = j.astype(np.int16)
            if not self.exact_identity:
                small = sigma < self.SMALL
                j[small], t[small] = 0, 0.0
        self.j, self.t = j.ravel(), t.ravel()
        self._order = None

    def scaled(self, k: float) -> "_Levels":
        """The plan of k·σ: the same pixels per level unless k·σ crosses 1/8 px somewhere."""
        if self.exact_identity and k * self.lo >= self.SMALL:
            other = object.__new__(_Levels)
            other.__dict__.update(self.__dict__)
            other.levels = self.levels * k
            other.scale = self.scale * k
            return other
        return _Levels(k * self.sigma)

    def crop(self, shape: tuple[int, int], box: tuple[int, int, int, int]) -> "_Levels":
        """The plan of the pixels in ``box`` (y0, y1, x0, x1) of an image of ``shape``: the same
        levels, each pixel's j and t kept."""
        y0, y1, x0, x1 = box
        other = object.__new__(_Levels)
        other.__dict__.update(self.__dict__)
        other.sigma = self.sigma[y0:y1, x0:x1]
        other.j = self.j.reshape(shape)[y0:y1, x0:x1].ravel()
        other.t = self.t.reshape(shape)[y0:y1, x0:x1].ravel()
        other._w, other._order = {}, None
        return other

    def weights(self, lv: int):
        """Pixels fed by level ``lv`` and their weights: a dense (H·W,) float32 map where
        many pixels use it, else (indices, weights)."""
        if lv in self._w:
            return self._w[lv]
        self._w[lv] = w = self._weights(lv)
        return w

    def _weights(self, lv: int):
        n = self.j.size
        if self._order is None:  # pixels sorted by level (radix sort of int16)
            cnt = np.bincount(self.j, minlength=len(self.levels))
            self._order = np.argsort(self.j, kind="stable")
            self._ends = np.cumsum(cnt)
            self._starts = self._ends - cnt
        lo_n = self._ends[lv] - self._starts[lv]
        hi_n = self._ends[lv - 1] - self._starts[lv - 1] if lv > 0 else 0
        if lo_n + hi_n == 0:
            return None
        if lo_n + hi_n > n // 8:
            w = np.where(self.j == lv, 1.0 - self.t, np.float32(0.0))
            if hi_n:
                w += np.where(self.j == lv - 1, self.t, np.float32(0.0))
            return w
        idx = np.concatenate([self._order[self._starts[lv]:self._ends[lv]],
                              self._order[self._starts[lv - 1]:self._ends[lv - 1]] if hi_n else np.zeros(0, np.int64)])
        w = np.concatenate([1.0 - self.t[idx[:lo_n]], self.t[idx[lo_n:]]])
        return idx, w


def _blur_planes_axis(planes: list[np.ndarray], sigma, axis: int, valid: np.ndarray | None,
                      norm=None) -> list[np.ndarray]:
    """Gaussian blur of float32 (H, W) planes along ``axis`` (0 = y, 1 = x) with σ (pixels)
    a float or per pixel (a :class:`_Levels`); taps where ``valid`` is 0 are left out (weights
    renormalised; no valid tap: unchanged), boundary mirrored (scipy ``reflect``).  ``norm``:
    :func:`_mask_norm` of the same σ, axis and ``valid`` when known (it does not depend on the
    planes).

    A per-pixel σ is a blur whose kernel at a pixel is the Gaussian of that pixel's σ (the
    gather of :func:`_blur_axis`).  It is evaluated as uniform blurs (:func:`_blur_1d`) at
    the σ levels, the kernel of a pixel between two levels being interpolated linearly in σ
    between theirs: exact for pixels on a level (σ maps with two values, the extremes,
    σ < 1/8 px), within ~(ratio − 1)²/4 of the kernel elsewhere.
    """
    if valid is None:
        return _blur_sum(planes, sigma, axis)
    v = valid.astype(np.float32, copy=False)
    ok, inv = _mask_norm(sigma, axis, v) if norm is None else norm
    acc = _blur_sum([p * v for p in planes], sigma, axis)
    return [np.where(ok, n * inv, p) for n, p in zip(acc, planes)]


def _mask_norm(sigma, axis: int, v: np.ndarray):
    """(where the blurred mask is > 0, 1 / the blurred mask there) for :func:`_blur_planes_axis`."""
    den = _blur_sum([v.astype(np.float32, copy=False)], sigma, axis)[0]
    ok = den > 1e-12
    return ok, np.float32(1.0) / np.where(ok, den, np.float32(1.0))


def _blur_sum(srcs: list[np.ndarray], sigma, axis: int) -> list[np.ndarray]:
    """The planes blurred along ``axis`` with σ a float or a :class:`_Levels` (see
    :func:`_blur_planes_axis`), without a mask."""
    import cv2

    if not isinstance(sigma, _Levels):
        return [_blur_1d(a, float(sigma), axis) for a in srcs]
    shape = srcs[0].shape
    acc = [np.zeros(shape, np.float32) for _ in srcs]
    for lv, s in enumerate(sigma.levels):
        w = sigma.weights(lv)
        if w is None:
            continue
        for a, out in zip(srcs, acc):
            b = _blur_1d(a, float(s), axis)
            if isinstance(w, np.ndarray):
                cv2.accumulateProduct(b, w.reshape(shape), out)
            else:
                idx, ww = w
                out.ravel()[idx] += ww * b.ravel()[idx]
    return acc


def _blur_axis(img: np.ndarray, sigma: np.ndarray, axis: int, valid: np.ndarray | None) -> np.ndarray:
    """Gaussian blur along ``axis`` (0 = y, 1 = x) with a per-pixel σ (pixels): the exact
    per-pixel gather (O(4σ) numpy passes; the reference for :func:`_blur_planes_axis`).

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


def sss_blur(irradiance: np.ndarray, mm_per_pixel: float | np.ndarray, depth: np.ndarray | None = None,
             profile=SKIN_PROFILE, mask: np.ndarray | None = None, axis_blur=None) -> np.ndarray:
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
    axis_blur    optional replacement of the one-axis Gaussian blur (a backend's):
                 ``axis_blur(planes, sigma, axis, valid) -> planes`` with the semantics of
                 :func:`_blur_planes_axis` (σ in pixels: a float, or a :class:`_Levels` whose
                 ``sigma`` is the per-pixel map).
    Returns float32 (H, W, C).  (:class:`Scatter` keeps what does not depend on the irradiance,
    for many irradiances on one surface.)
    """
    img = np.asarray(irradiance, dtype=np.float32)
    if img.ndim not in (2, 3):
        raise ValueError(f"irradiance must be H×W×C, got shape {img.shape}")
    return Scatter(img.shape, mm_per_pixel, depth, profile, mask, axis_blur)(img)


class Scatter:
    """:func:`sss_blur` prepared for one surface: the pixel steps, the mask, the σ plans of every
    Gaussian and the mask's own blurs (which do not depend on the irradiance) are computed once;
    ``scatter(irradiance)`` is ``sss_blur(irradiance, …)`` (a live view re-shading one face
    keeps it).  ``shape``: the irradiance's, (H, W) or (H, W, C).

    ``crop`` (with a mask): the passes run on the mask's bounding box grown by the widest
    kernel, not the whole frame.  Pixels outside the mask are returned unchanged and get no
    weight, so this is the same blur; only the floating-point rounding of the filters may differ
    in the last bits (a pixel's place in cv2's vector loops, a level's pixels gathered densely or
    sparsely).
    """

    def __init__(self, shape, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None, axis_blur=None,
                 crop: bool = False):
        self.shape = tuple(shape)
        h, w = self.shape[:2]
        c = 1 if len(self.shape) == 2 else self.shape[2]
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
            valid = (np.asarray(mask) > 0.5).astype(np.float32)
        step_x, step_y = _pixel_step_mm(mpp, depth, (h, w))
        uniform = _uniform(step_x) and _uniform(step_y)
        if uniform:  # one σ per axis and Gaussian
            step_x, step_y = float(step_x.flat[0]), float(step_y.flat[0])
        else:  # per-pixel σ ∝ 1/step: one level plan per axis, scaled for each Gaussian
            plan_y, plan_x = _Levels(1.0 / step_y), _Levels(1.0 / step_x)
        passes = []
        for var, rgb in profile:
            wts = np.zeros(c)
            wts[: min(c, 3)] = np.asarray(rgb, np.float64)[: min(c, 3)]
            if c > 3:
                wts[3:] = rgb[-1]
            chans = [ch for ch in range(c) if wts[ch] != 0]  # only the channels this Gaussian feeds
            if not chans:
                continue
            sd = float(np.sqrt(var))
            sy, sx = (sd / step_y, sd / step_x) if uniform else (plan_y.scaled(sd), plan_x.scaled(sd))
            passes.append([chans, [np.float32(wts[ch]) for ch in chans], sy, sx])
        self.box = None
        if crop and valid is not None and axis_blur is None:
            self.box = _grown_box(valid, 1 + max((_radius(s) for p in passes for s in p[2:]), default=0))
            y0, y1, x0, x1 = self.box
            if y0 == y1:  # no skin: every pixel is returned unchanged
                passes = []
            valid = np.ascontiguousarray(valid[y0:y1, x0:x1])
            for p in passes:
                p[2:] = [s if isinstance(s, float) else s.crop((h, w), self.box) for s in p[2:]]
        self.valid, self.axis_blur = valid, axis_blur
        for p in passes:  # the mask's blurs: the normalisation of both axes
            p.append(None if valid is None or axis_blur is not None else
                     (_mask_norm(p[2], 0, valid), _mask_norm(p[3], 1, valid)))
        self.passes = passes

    def __call__(self, irradiance: np.ndarray) -> np.ndarray:
        img = np.asarray(irradiance, dtype=np.float32)
        if img.shape != self.shape:
            raise ValueError(f"irradiance must be {self.shape}, got shape {img.shape}")
        squeeze = img.ndim == 2
        if squeeze:
            img = img[:, :, None]
        sub = img
        if self.box is not None:
            y0, y1, x0, x1 = self.box
            sub = img[y0:y1, x0:x1]
        valid, axis_blur = self.valid, self.axis_blur
        planes = [np.ascontiguousarray(sub[:, :, ch]) for ch in range(sub.shape[2])]

        def scatter(chans, wts, sy, sx, norms):
            mine = [planes[ch] for ch in chans]
            if axis_blur is not None:
                return axis_blur(axis_blur(mine, sy, 0, valid), sx, 1, valid)
            if valid is None and isinstance(sy, float):
                return [_blur_1d(_blur_1d(a, sy, 0), sx, 1) for a in mine]
            # y then x, each normalised by the blurred mask (light stays in the skin)
            ny, nx = norms if norms is not None else (None, None)
            return _blur_planes_axis(_blur_planes_axis(mine, sy, 0, valid, ny), sx, 1, valid, nx)

        # the Gaussians on the cores (cv2 and numpy release the GIL), summed in profile order
        done = [scatter(*p) for p in self.passes] if axis_blur is not None else \
            run_tasks([functools.partial(scatter, *p) for p in self.passes])
        out = [np.zeros(sub.shape[:2], np.float32) for _ in planes]
        for (chans, wts, *_), blurred in zip(self.passes, done):
            for ch, wt, b in zip(chans, wts, blurred):
                out[ch] += wt * b
        res = np.stack(out, axis=-1)
        if valid is not None:
            res = np.where(valid[..., None] > 0, res, sub)
        if self.box is not None:
            full = img.copy()
            full[y0:y1, x0:x1] = res
            res = full
        return res[:, :, 0] if squeeze else res


def _radius(sigma) -> int:
    """The widest kernel radius (pixels) of a σ (a float or a :class:`_Levels`)."""
    top = float(sigma) if isinstance(sigma, float) else float(np.max(sigma.levels))
    return int(TRUNCATE * top + 0.5)


def _grown_box(valid: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the bounding box of ``valid`` > 0 grown by ``margin``, inside the image."""
    h, w = valid.shape
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    if rows.size == 0:
        return 0, 0, 0, 0
    return (int(max(0, rows[0] - margin)), int(min(h, rows[-1] + 1 + margin)),
            int(max(0, cols[0] - margin)), int(min(w, cols[-1] + 1 + margin)))


def _uniform(sigma: np.ndarray) -> bool:
    flat = sigma.ravel()
    return bool(flat.size) and bool(np.all(flat == flat[0]))


__all__ = ["SKIN_PROFILE", "Scatter", "sss_blur"]
