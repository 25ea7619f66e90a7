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
``reflect`` boundary (:func:`gaussian_kernel`, :func:`_blur_1d`).  Where σ varies per pixel,
the kernel at a pixel is the Gaussian of that pixel's σ (the gather :func:`_blur_axis`, kept as
the reference); it is evaluated as a few uniform blurs at σ levels a factor ``LEVEL_RATIO`` = 2
apart (a small stack of widths, as a mip stack), each pixel's kernel interpolated linearly in σ
between the two levels around its σ, with per-pixel weights made once per surface
(:func:`_axis_terms`): exact on the levels (the extremes, two-valued footprints,
σ < IDENTITY_SIGMA ≈ 0.17 px), elsewhere within ~1 % of a step edge's height and ≥ 55 dB PSNR
on a photo (measured against the gather and against the sum of erfs of a step in
tests/test_jimenez_nodes.py and tests/test_sss.py).  With ``taps`` (a Scatter cropped to a
skin mask; CosmeticShade's) the passes that reach at most TAP_RADIUS pixels are instead
evaluated as per-pixel tap maps summed from the levels' weights (:func:`_tap_maps`): the same
per-pixel kernels, float rounding apart, at about half the cost.  At a pixel the standard
deviation in pixels along an image axis is

    σ_px = √v_i / ℓ,     ℓ = √(mm_per_pixel² + (∂depth/∂axis)²)   [mm per pixel step on the surface]

where ``depth`` is in mm and its derivative is taken by central differences (pixels).  On a flat
depth (or without depth) and a scalar ``mm_per_pixel``, the result is the weighted sum of
``scipy.ndimage.gaussian_filter`` results (same 4σ truncation, same ``reflect`` boundary; equal
to float32 round-off, ~1e-7 relative).

Public, stable API (also used by the Huang 2013 cosmetics nodes)::

    SKIN_PROFILE: tuple[(variance_mm2, (w_r, w_g, w_b)), ...]
    sss_blur(irradiance, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None) -> ndarray
    sss_blur_plane(plane, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None, channels=3) -> ndarray
    Scatter(shape, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None, crop=False,
            taps=False)(irradiance)
    Scatter.on_box(irradiance_on_box, out=None), Scatter.update(irradiance_on_box, before, after, out=None)
    fold_faint(profile=SKIN_PROFILE, below=FAINT) -> profile   (CosmeticShade's: fewer channel blurs)
"""
from __future__ import annotations

import functools
import os
import threading
from typing import NamedTuple

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

#: a channel's weight below this in one Gaussian of a profile is moved to that channel's
#: nearest Gaussian (in variance) of a larger weight by :func:`fold_faint`
FAINT = 0.01


def fold_faint(profile=SKIN_PROFILE, below: float = FAINT):
    """``profile`` with each channel's weights below ``below`` moved onto the Gaussian of that
    channel nearest in log variance among those it keeps (each channel's sum unchanged), so
    those channels are not blurred at those widths: for SKIN_PROFILE the green and blue 0.7 %
    at 0.567 mm² (to 0.187 and 0.0484 mm²) and the green 0.4 % at 1.99 mm² (to 0.187), three
    of the eleven channel blurs, ~28 % of a scatter's work.  The scatter moves by ≤ 0.21 % of
    a step's height (a unit step on a per-pixel σ, tests/test_sss.py), far under the σ
    levels' own ~1 % (LEVEL_RATIO); CosmeticShade's scatter uses it."""
    var = [v for v, _ in profile]
    w = np.array([rgb for _, rgb in profile], np.float64)
    out = w.copy()
    for ch in range(w.shape[1]):
        keep = [i for i in range(len(var)) if w[i, ch] >= below]
        for i in np.flatnonzero((w[:, ch] > 0) & (w[:, ch] < below)):
            if keep:
                k = min(keep, key=lambda k: abs(np.log(var[k] / var[i])))
                out[k, ch] += w[i, ch]
                out[i, ch] = 0.0
    return tuple((v, tuple(float(x) for x in row)) for v, row in zip(var, out))


TRUNCATE = 4.0  # kernel radius in standard deviations (as scipy.ndimage.gaussian_filter)
#: ratio between successive σ levels of a per-pixel σ (depth gradient, pixel footprint map):
#: a factor 2 keeps a blurred step within ~1 % of its height (levels 2 % apart: 1e-4, at ~4×
#: the passes)
LEVEL_RATIO = 2.0
#: a pixel step (so a σ) map whose values lie within this ratio on both axes is blurred as
#: uniform, at its geometric mean: each pixel's σ off by ≤ 1 %, a blurred step by ≤ 0.25 % of
#: its height (well inside LEVEL_RATIO's ~1 %), at the cost of one blur instead of two levels
NEAR_UNIFORM = 1.02


def _pixel_step_mm(mm_per_pixel, depth, shape) -> tuple[np.ndarray, np.ndarray]:
    """Surface length (mm) covered by one pixel step along x and along y, per pixel."""
    h, w = shape
    mpp = np.broadcast_to(np.asarray(mm_per_pixel, dtype=np.float64), (h, w))
    if depth is None:
        return mpp, mpp
    d = np.asarray(depth, dtype=np.float64)
    gy, gx = (np.gradient(d) if min(h, w) > 1 else (np.zeros_like(d), np.zeros_like(d)))
    return np.sqrt(mpp ** 2 + gx ** 2), np.sqrt(mpp ** 2 + gy ** 2)


#: below this σ (px) a Gaussian's first side tap exp(−1/2σ²) is < 2⁻²⁴ of its centre tap,
#: under float32's rounding: its kernel is the identity
IDENTITY_SIGMA = float((48 * np.log(2)) ** -0.5)


@functools.lru_cache(maxsize=256)
def gaussian_kernel(sigma: float) -> np.ndarray:
    """scipy.ndimage's Gaussian: taps exp(−k²/2σ²) for |k| ≤ int(4σ + 0.5), normalised to
    sum 1 (float32, read-only); one tap below IDENTITY_SIGMA."""
    R = int(TRUNCATE * sigma + 0.5) if sigma >= IDENTITY_SIGMA else 0
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
    towards level j + 1.  Level 0 is σ = 0 (the identity: every σ < IDENTITY_SIGMA has a
    one-tap kernel, so those pixels are exact); then σ_lo … σ_max in geometric steps (both ends exact)
    of at most LEVEL_RATIO.  ``scaled``
    gives the levels of k·σ with the same j, t (the six Gaussians share one plan per axis)."""

    SMALL = IDENTITY_SIGMA  # one-tap kernels below it

    def __init__(self, sigma: np.ndarray):
        lo, hi = float(sigma.min()), float(sigma.max())
        self.sigma, self.lo = sigma, lo
        self.scale = 1.0  # the per-pixel σ (px) is scale · sigma (see scaled)
        self.exact_identity = lo >= self.SMALL  # no identity pixels to separate
        lo = max(lo, self.SMALL)
        if hi < self.SMALL:
            self.levels = np.zeros(1)
            j, t = np.zeros(sigma.shape, np.int16), np.zeros(sigma.shape, np.float32)
        else:
            n = 1 if hi <= lo else int(np.ceil(np.log(hi / lo) / np.log(LEVEL_RATIO))) + 1
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

    def scaled(self, k: float) -> "_Levels":
        """The plan of k·σ: the same pixels per level unless k·σ crosses IDENTITY_SIGMA somewhere."""
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
        return other

    def dense(self, lv: int) -> np.ndarray | None:
        """The (H, W) float32 weights of level ``lv`` at each pixel (1 − t where j = lv, t where
        j = lv − 1), or None where no pixel uses it."""
        w = np.where(self.j == lv, np.float32(1.0) - self.t, np.float32(0.0))
        if lv > 0:
            w += np.where(self.j == lv - 1, self.t, np.float32(0.0))
        return w.reshape(self.sigma.shape) if w.any() else None


class _Term(NamedTuple):
    """One uniform blur of an axis pass and where its result goes: ``weight`` (None: everywhere,
    weight 1) on the rows y0:y1 and columns x0:x1 (the box of its non-zero weights)."""
    sigma: float
    weight: np.ndarray | None
    box: tuple[int, int, int, int]


def _axis_terms(sigma, axis: int, valid: np.ndarray | None, shape) -> list[_Term]:
    """The Gaussian blur along ``axis`` (0 = y, 1 = x) with σ (pixels) a float or per pixel (a
    :class:`_Levels`), as uniform blurs whose results are summed with per-pixel weights:
    out = Σ weight · _blur_1d(src, σ).  With ``valid`` (a 0/1 mask) the source is the planes
    times ``valid`` (taps off the mask left out), the weights hold the normalisation by the
    blurred mask and are zero off the mask (so the next pass reads its source from them).

    A per-pixel σ is a blur whose kernel at a pixel is the Gaussian of that pixel's σ (the
    gather of :func:`_blur_axis`, the reference).  It is evaluated as uniform blurs at the σ
    levels, the kernel of a pixel between two levels being interpolated linearly in σ between
    theirs: exact for pixels on a level (σ maps with two values, the extremes, σ < IDENTITY_SIGMA),
    within the interpolation error of the level ratio elsewhere (measured in
    tests/test_jimenez_nodes.py).  Only the maps of weights depend on the surface, so they are
    made once per surface (:class:`Scatter`)."""
    h, w = shape
    if isinstance(sigma, _Levels):
        terms = [(float(s), d) for lv, s in enumerate(sigma.levels) if (d := sigma.dense(lv)) is not None]
    else:
        terms = [(float(sigma), None)]
    if valid is not None:  # light stays in the skin: normalise by the blurred mask, zero off it
        den = np.zeros(shape, np.float32)
        for s, d in terms:
            b = _blur_1d(valid, s, axis)
            den += b if d is None else d * b
        scale = np.where(den > 1e-12, valid / np.where(den > 1e-12, den, np.float32(1.0)), np.float32(0.0))
        terms = [(s, scale if d is None else d * scale) for s, d in terms]
    return [_Term(s, d, (0, h, 0, w)) if d is None else _trimmed(s, d) for s, d in terms]


def _trimmed(sigma: float, weight: np.ndarray) -> _Term:
    """A term whose weights are kept on their non-zero box only."""
    y0, y1, x0, x1 = _grown_box(weight, 0)
    return _Term(sigma, np.ascontiguousarray(weight[y0:y1, x0:x1]), (y0, y1, x0, x1))


#: a per-pixel σ pass whose widest kernel reaches at most this far (pixels) is evaluated as tap
#: maps (:func:`_tap_maps`, Scatter's ``taps``) instead of one uniform blur per σ level
TAP_RADIUS = 6


class _Taps(NamedTuple):
    """An axis pass as per-pixel tap maps along the axis:
    out(x) = c₀(x)·src(x) + Σ_j c_j(x)·(src(x − j) + src(x + j)), j = 1 … ``radius``;
    ``coef`` the (H, W) float32 maps c₀ … c_radius, all 0 off ``box`` (y0, y1, x0, x1)."""
    radius: int
    coef: list
    box: tuple


def _tap_maps(terms: list[_Term], axis: int, shape) -> _Taps | None:
    """The weighted uniform blurs ``terms`` (:func:`_axis_terms`) as per-pixel tap maps: c_j =
    Σ_terms weight · tap j of the term's Gaussian (the Gaussians are symmetric, and the weights
    already hold the mask's normalisation and are zero off it, so the source is the plane times
    the mask as for the terms): the same kernel at every pixel, float rounding apart.  One
    multiply-add per tap and pixel instead of a blur and a weighted sum per level: cheaper while
    the kernels are short.  None when the widest reaches past TAP_RADIUS, when there is a single
    uniform blur, or when a pixel with weight lies within the reach of the plane's edge (there
    the blurs reflect the border)."""
    R = max(gaussian_kernel(t.sigma).size // 2 for t in terms)
    if R > TAP_RADIUS or (len(terms) == 1 and terms[0].weight is None):
        return None
    h, w = shape
    coef = [np.zeros(shape, np.float32) for _ in range(R + 1)]
    for sigma, weight, (y0, y1, x0, x1) in terms:
        k = gaussian_kernel(sigma)
        r = k.size // 2
        wt = np.ones((y1 - y0, x1 - x0), np.float32) if weight is None else weight
        for j in range(r + 1):
            coef[j][y0:y1, x0:x1] += wt * k[r + j]
    ends = [slice(0, R), slice((h if axis == 0 else w) - R, None)]
    edge = ends if axis == 0 else [(slice(None), e) for e in ends]
    if R and any(np.any(c[e]) for c in coef for e in edge):
        return None
    box = _grown_box(np.logical_or.reduce([cj != 0 for cj in coef]), 0)
    return _Taps(R, coef, box if box[0] < box[1] else (0, 0, 0, 0))


def _reach(terms) -> int:
    """How far (pixels) an axis pass reads from a pixel (:func:`_axis_terms` or :func:`_tap_maps`)."""
    if isinstance(terms, _Taps):
        return terms.radius
    return max((gaussian_kernel(t.sigma).size // 2 for t in terms), default=0)


class _Work:
    """Float32 buffers kept between calls, by name: a fresh 1280×720 plane costs ~1 ms of page
    faults when first written (the kernel zeroes its pages), as much as a short blur of it, and
    a scatter would fault ~60 MB per call."""

    def __init__(self):
        self._bufs: dict = {}

    def get(self, name, rows: int, cols: int) -> np.ndarray:
        """A (rows, cols) C-contiguous float32 array (contents undefined)."""
        n = rows * cols
        buf = self._bufs.get(name)
        if buf is None or buf.size < n:
            buf = self._bufs[name] = np.empty(n, np.float32)
        return buf[:n].reshape(rows, cols)


#: the spare sets of buffers (one _Work per band), shared by every Scatter; a call takes one
_SPARE: list = []


def _band_terms(src: np.ndarray, off: int, terms: list[_Term], axis: int, rows: tuple[int, int],
                work: _Work, name: str) -> np.ndarray:
    """Rows r0:r1 (``rows``) of Σ weight · _blur_1d(plane, σ) over the terms of
    :func:`_axis_terms`, where ``src`` holds the plane's rows off : off + len(src) (for
    ``axis`` 0 all of them; for axis 1 at least r0:r1).  Each blur is made on its term's box
    within the rows only (grown by the kernel's radius along ``axis``, within the plane: the
    same taps, the same reflected border and the same columns as a blur of the whole plane, so
    the same bytes).  Returns (r1 − r0, W) float32: a view of ``src`` or of ``work``'s buffers."""
    import cv2

    r0, r1 = rows
    width = src.shape[1]
    if isinstance(terms, _Taps):
        return _band_taps(src, off, terms, axis, rows, work, name)
    if len(terms) == 1 and terms[0].weight is None:
        return _blur_rows(src, off, terms[0].sigma, axis, (r0, r1, 0, width), work, name + "t")
    acc = work.get(name, r1 - r0, width)
    started = False
    for s, wt, (y0, y1, x0, x1) in terms:
        a, b = max(y0, r0), min(y1, r1)
        if a >= b or x0 == x1:  # no weight in these rows
            continue
        blurred = _blur_rows(src, off, s, axis, (a, b, x0, x1), work, name + "t")
        w = None if wt is None else wt[a - y0:b - y0]
        if not started and (a, b, x0, x1) == (r0, r1, 0, width):  # the first term covers the band
            if w is None:
                np.copyto(acc, blurred)
            else:
                cv2.multiply(blurred, w, dst=acc)
        else:
            if not started:
                acc.fill(0.0)
            region = acc[a - r0:b - r0, x0:x1]
            if w is None:
                region += blurred
            else:
                cv2.accumulateProduct(blurred, w, region)
        started = True
    if not started:
        acc.fill(0.0)
    return acc


def _band_taps(src: np.ndarray, off: int, taps: _Taps, axis: int, rows: tuple[int, int], work: _Work,
               name: str) -> np.ndarray:
    """Rows r0:r1 (``rows``) of an axis pass by tap maps (:class:`_Taps`), ``src`` holding the
    plane's rows from ``off`` (as :func:`_band_terms`): made on the maps' box (0 off it, where
    every map is 0; it lies within the reach of the plane's edges, :func:`_tap_maps`)."""
    import cv2

    r0, r1 = rows
    R, c = taps.radius, taps.coef
    y0, y1, x0, x1 = taps.box
    acc = work.get(name, r1 - r0, src.shape[1])
    a, b = max(r0, y0), min(r1, y1)
    if a >= b:
        acc.fill(0.0)
        return acc
    acc[:a - r0] = 0.0
    acc[b - r0:] = 0.0
    acc[a - r0:b - r0, :x0] = 0.0
    acc[a - r0:b - r0, x1:] = 0.0

    def at(j):  # the source j pixels along the axis from the box's rows a:b and columns
        if axis == 0:
            return src[a + j - off:b + j - off, x0:x1]
        return src[a - off:b - off, x0 + j:x1 + j]

    out, here = acc[a - r0:b - r0, x0:x1], (slice(a, b), slice(x0, x1))
    pair = work.get(name + "s", b - a, x1 - x0)
    cv2.multiply(at(0), c[0][here], dst=out)
    for j in range(1, R + 1):
        cv2.add(at(-j), at(j), dst=pair)
        cv2.accumulateProduct(pair, c[j][here], out)
    return acc


def _blur_rows(src: np.ndarray, off: int, sigma: float, axis: int, box, work: _Work, name: str) -> np.ndarray:
    """_blur_1d(plane, σ, axis)[y0:y1, x0:x1] (``box``), ``src`` holding the plane's rows from
    ``off``: the blur of the box grown by the kernel's radius along ``axis`` (cut at the plane's
    edges, where the border is reflected as in the whole plane), into ``work``'s buffer
    ``name``; the identity (a one-tap kernel) is a view of ``src``."""
    import cv2

    y0, y1, x0, x1 = box
    k = gaussian_kernel(sigma)
    if k.size == 1:
        return src[y0 - off:y1 - off, x0:x1]
    r = k.size // 2
    if axis == 0:
        a0, a1 = max(0, y0 - r), min(off + src.shape[0], y1 + r)
        out = work.get(name, a1 - a0, x1 - x0)
        cv2.filter2D(src[a0 - off:a1 - off, x0:x1], -1, k.reshape(-1, 1), dst=out, borderType=cv2.BORDER_REFLECT)
        return out[y0 - a0:y1 - a0]
    a0, a1 = max(0, x0 - r), min(src.shape[1], x1 + r)
    out = work.get(name, y1 - y0, a1 - a0)
    cv2.filter2D(src[y0 - off:y1 - off, a0:a1], -1, k.reshape(1, -1), dst=out, borderType=cv2.BORDER_REFLECT)
    return out[:, x0 - a0:x1 - a0]


def _blur_axis(img: np.ndarray, sigma: np.ndarray, axis: int, valid: np.ndarray | None) -> np.ndarray:
    """Gaussian blur along ``axis`` (0 = y, 1 = x) with a per-pixel σ (pixels): the exact
    per-pixel gather (O(4σ) numpy passes; the reference for :func:`_axis_terms`).

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
                 ``axis_blur(planes, sigma, axis, valid) -> planes``: the planes blurred along
                 ``axis`` with σ in pixels (a float, or a :class:`_Levels` whose ``sigma`` is
                 the per-pixel map), taps where ``valid`` is 0 left out and the weights
                 renormalised (no valid tap: unchanged), as the gather :func:`_blur_axis`.
    Returns float32 (H, W, C).  (:class:`Scatter` keeps what does not depend on the irradiance,
    for many irradiances on one surface.)
    """
    img = np.asarray(irradiance, dtype=np.float32)
    if img.ndim not in (2, 3):
        raise ValueError(f"irradiance must be H×W×C, got shape {img.shape}")
    if axis_blur is not None:
        return Scatter(img.shape, mm_per_pixel, depth, profile, mask, axis_blur)(img)
    return _scatter(img.shape, mm_per_pixel, depth, profile, mask)(img)


def sss_blur_plane(plane: np.ndarray, mm_per_pixel: float | np.ndarray, depth: np.ndarray | None = None,
                   profile=SKIN_PROFILE, mask: np.ndarray | None = None, channels: int = 3) -> np.ndarray:
    """sss_blur of the (H, W, ``channels``) irradiance whose every channel is ``plane`` (H, W),
    bit for bit, each Gaussian blurred once (not once per channel): the scatter of a light of
    one colour, ``col · sss_blur_plane(N·L)`` (the scatter is linear).  Returns float32
    (H, W, channels)."""
    p = np.asarray(plane, dtype=np.float32)
    if p.ndim != 2:
        raise ValueError(f"plane must be H×W, got shape {p.shape}")
    return _scatter(p.shape + (channels,), mm_per_pixel, depth, profile, mask).plane(p)


def _scatter(shape, mm_per_pixel, depth, profile, mask) -> "Scatter":
    """The Scatter of a surface: made afresh for one σ per Gaussian and no mask (nothing per
    surface to keep), else the memoised one (:func:`_prepared`)."""
    if depth is None and mask is None and np.ndim(mm_per_pixel) == 0:
        return Scatter(shape, mm_per_pixel, depth, profile, mask)
    return _prepared(shape, mm_per_pixel, depth, profile, mask)


#: the last Scatters by the digest of their surface (a live view re-shading one face, a
#: benchmark): their per-pixel weight maps, ~100–200 MB for a whole 1280×720 frame
_SCATTERS: dict = {}
_SCATTERS_LOCK = threading.Lock()


def _prepared(shape, mm_per_pixel, depth, profile, mask) -> "Scatter":
    """Scatter(shape, mm_per_pixel, depth, profile, mask), memoised on the digest of its
    arguments (what does not depend on the irradiance is made once per surface)."""
    import xxhash

    h = xxhash.xxh3_128(repr((tuple(shape), tuple(profile))).encode())
    for a in (mm_per_pixel, depth, mask):
        a = None if a is None else np.ascontiguousarray(a)
        h.update(b"none" if a is None else repr((a.dtype.str, a.shape)).encode())
        if a is not None:
            h.update(a)
    key = h.hexdigest()
    got = _SCATTERS.get(key)
    if got is None:
        got = Scatter(shape, mm_per_pixel, depth, profile, mask)
        with _SCATTERS_LOCK:  # nodes may run on several threads (graphkit run --jobs)
            while len(_SCATTERS) >= 2:
                _SCATTERS.pop(next(iter(_SCATTERS)))
            _SCATTERS[key] = got
    return got


class Scatter:
    """:func:`sss_blur` prepared for one surface: the pixel steps, the mask, the σ plans of every
    Gaussian and the mask's own blurs (which do not depend on the irradiance) are computed once;
    ``scatter(irradiance)`` is ``sss_blur(irradiance, …)`` (a live view re-shading one face
    keeps it).  ``shape``: the irradiance's, (H, W) or (H, W, C).

    ``crop`` (with a mask): the passes run on the mask's bounding box grown by the widest
    kernel, not the whole frame.  Pixels outside the mask are returned unchanged and get no
    weight, so this is the same blur; only the floating-point rounding of the filters may differ
    in the last bits (a pixel's place in cv2's vector loops, a level's pixels gathered densely or
    sparsely).  ``taps`` (with ``crop``): the narrow passes as per-pixel tap maps (:func:`_tap_maps`).
    """

    def __init__(self, shape, mm_per_pixel, depth=None, profile=SKIN_PROFILE, mask=None, axis_blur=None,
                 crop: bool = False, taps: bool = False):
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
        uniform = _near_uniform(step_x) and _near_uniform(step_y)
        if uniform:  # one σ per axis and Gaussian
            step_x, step_y = _mean_step(step_x), _mean_step(step_y)
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
        self._off = None if valid is None else valid <= 0
        if axis_blur is None:  # each axis as weighted uniform blurs (the weights: surface only)
            hw = (h, w) if self.box is None else (self.box[1] - self.box[0], self.box[3] - self.box[2])
            for p in passes:
                p[2:] = [_axis_terms(p[2], 0, valid, hw), _axis_terms(p[3], 1, valid, hw)]
                if taps and self.box is not None:  # narrow per-pixel kernels as tap maps
                    p[2:] = [_tap_maps(p[2], 0, hw) or p[2], _tap_maps(p[3], 1, hw) or p[3]]
            self._row_cost = _row_costs(passes, hw)
            self._reach = max((_reach(terms) for p in passes for terms in p[2:3]), default=0)
        self.passes = passes

    def __call__(self, irradiance: np.ndarray) -> np.ndarray:
        img = np.asarray(irradiance, dtype=np.float32)
        if img.shape != self.shape:
            raise ValueError(f"irradiance must be {self.shape}, got shape {img.shape}")
        squeeze = img.ndim == 2
        if squeeze:
            img = img[:, :, None]
        if self.box is None:
            res = self.on_box(img)
        else:
            y0, y1, x0, x1 = self.box
            res = img.copy()
            self.on_box(img[y0:y1, x0:x1], out=res[y0:y1, x0:x1])
        return res[:, :, 0] if squeeze else res

    def plane(self, plane: np.ndarray) -> np.ndarray:
        """``self(irradiance)`` for the irradiance whose every channel is ``plane`` ((H, W)): the
        same bytes, with one blur per Gaussian instead of one per Gaussian and channel (a light
        of one colour: the scatter is linear, so col · self.plane(N·L) is its scatter)."""
        p = np.asarray(plane, dtype=np.float32)
        if len(self.shape) != 3 or p.shape != self.shape[:2]:
            raise ValueError(f"plane must be {self.shape[:2]} for a scatter of {self.shape}, got shape {p.shape}")
        if self.axis_blur is not None:
            return self(np.repeat(p[:, :, None], self.shape[2], axis=2))
        sub = p[:, :, None]
        if self.box is None:
            return self.on_box(sub, out=np.empty(self.shape, np.float32))
        y0, y1, x0, x1 = self.box
        res = np.repeat(sub, self.shape[2], axis=2)
        self.on_box(sub[y0:y1, x0:x1], out=res[y0:y1, x0:x1])
        return res

    def on_box(self, sub: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The scattered irradiance on :attr:`box` (the whole frame when None) from the
        irradiance there, (h, w, C) float32: what ``self(irradiance)`` puts in the box (outside
        it the irradiance is returned unchanged).  Written into ``out`` when given (an (h, w, C)
        float32 array; it may be ``sub`` itself: all of ``sub`` is read before ``out`` is written).
        ``sub`` of one channel (h, w, 1) with ``out`` of C: the irradiance whose every channel is
        that plane, each Gaussian's blur made once (:meth:`plane`)."""
        out = np.empty(sub.shape, np.float32) if out is None else out
        if sub.size == 0:
            return out
        if self.axis_blur is not None:
            self._hooked(sub, out)
            return out
        self._rows(sub, out, (0, sub.shape[0]))
        return out

    def update(self, sub: np.ndarray, before: np.ndarray, after: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``on_box(sub)`` given ``after = on_box(before)`` (all (h, w, C) float32), written into
        ``out`` when given (not ``sub``): the rows farther than the y passes' widest reach from
        every row where ``sub`` differs from ``before`` are ``after``'s, the others are blurred
        again (a live view changing one cosmetic: the rows around it).  The same bytes as
        ``on_box(sub)``: each row of a pass is made from the same taps in the same order
        whatever rows are made with it (as for the bands, tests/test_sss.py)."""
        if sub.size == 0 or self.axis_blur is not None or sub.shape != before.shape:
            return self.on_box(sub, out)
        out = np.empty(sub.shape, np.float32) if out is None else out
        h = sub.shape[0]
        rows = np.flatnonzero(np.not_equal(sub, before).reshape(h, -1).any(axis=1))
        r0, r1 = (max(0, int(rows[0]) - self._reach), min(h, int(rows[-1]) + 1 + self._reach)) if rows.size else (h, h)
        np.copyto(out[:r0], after[:r0])
        np.copyto(out[r1:], after[r1:])
        if r0 < r1:
            self._rows(sub, out, (r0, r1))
        return out

    def _rows(self, sub, out, rows: tuple[int, int]) -> None:
        """Rows r0:r1 (``rows``) of on_box(sub) into ``out``, in bands of equal work on the cores."""
        h, w, c = sub.shape
        bands = self._bands(rows)
        works = _take_work(len(bands))
        try:  # the planes (times the mask) first: a band's y pass reads the rows around it
            # one contiguous plane not written over (out is not sub) is read where it is
            copy = not (c == 1 and sub[:, :, 0].flags.c_contiguous and not np.may_share_memory(sub, out))
            planes = [works[0].get(("plane", ch), h, w) for ch in range(c)] if copy else [sub[:, :, 0]]
            src = planes if self.valid is None else [works[0].get(("src", ch), h, w) for ch in range(c)]
            read = (max(0, rows[0] - self._reach), min(h, rows[1] + self._reach))  # what the y passes read
            run_tasks([functools.partial(self._split, sub, planes, src, b, copy) for b in self._bands(read)])
            run_tasks([functools.partial(self._band, planes, src, out, b, wk) for b, wk in zip(bands, works)])
        finally:
            _give_work(works)

    def _split(self, sub, planes, src, rows, copy: bool) -> None:
        """Rows r0:r1 of each channel's plane (``copy``: copied from ``sub``), and of the plane
        times the mask (the blurs' source)."""
        import cv2

        r0, r1 = rows
        for ch, plane in enumerate(planes):
            if copy:
                np.copyto(plane[r0:r1], sub[r0:r1, :, ch])
            if src is not planes:
                cv2.multiply(plane[r0:r1], self.valid[r0:r1], dst=src[ch][r0:r1])

    def _band(self, planes, src, out, rows, work: _Work) -> None:
        """Rows r0:r1 of the scattered irradiance into ``out``: per Gaussian and channel the y
        pass on those rows (reading the rows around them), the x pass, and the channel's sum."""
        r0, r1 = rows
        one = len(planes) == 1  # every channel is that plane: each Gaussian blurred once
        sums = [None] * out.shape[2]
        for chans, wts, ty, tx in self.passes:
            blurred = None
            for ch, wt in zip(chans, wts):
                if blurred is None or not one:
                    plane = src[0 if one else ch]
                    blurred = _band_terms(_band_terms(plane, 0, ty, 0, rows, work, "y"), r0, tx, 1, rows, work, "x")
                sums[ch] = _accumulate(sums[ch], blurred, wt, work.get(("sum", ch), r1 - r0, out.shape[1]))
        band = [p[r0:r1] for p in planes] * (len(sums) if one else 1)
        self._finish(sums, band, out[r0:r1], None if self._off is None else self._off[r0:r1])

    def _hooked(self, sub, out) -> None:
        """on_box through the backend's ``axis_blur`` (whole planes, one Gaussian after another)."""
        planes = [np.ascontiguousarray(sub[:, :, ch]) for ch in range(sub.shape[2])]
        sums = [None] * len(planes)
        for chans, wts, sy, sx in self.passes:
            done = self.axis_blur(self.axis_blur([planes[ch] for ch in chans], sy, 0, self.valid), sx, 1, self.valid)
            for ch, wt, b in zip(chans, wts, done):
                sums[ch] = _accumulate(sums[ch], b, wt, np.empty(planes[ch].shape, np.float32))
        self._finish(sums, planes, out, self._off)

    @staticmethod
    def _finish(sums, planes, dst, off) -> None:
        """dst = the channels' sums (a channel no Gaussian feeds: 0), the pixels off the skin
        (``off``) left as in ``planes``."""
        import cv2

        for ch, plane in enumerate(planes):
            if sums[ch] is None:
                sums[ch] = np.zeros(plane.shape, np.float32)
            if off is not None:
                np.copyto(sums[ch], plane, where=off)
        if len(sums) > 1:
            cv2.merge(sums, dst=dst)
        else:
            np.copyto(dst[:, :, 0], sums[0])

    def _bands(self, rows: tuple[int, int]) -> list[tuple[int, int]]:
        """Bands of rows r0:r1 (``rows``) of equal blur work (kernel taps × columns per row), one per core."""
        r0, r1 = rows
        cost = self._row_cost[r0:r1]
        n = max(1, min(os.cpu_count() or 1, 8, cost.size))
        cum = np.cumsum(cost)
        cuts = [0] + [int(np.searchsorted(cum, cum[-1] * k / n)) + 1 for k in range(1, n)] + [cost.size]
        cuts = sorted(set(min(max(x, 0), cost.size) + r0 for x in cuts))
        return list(zip(cuts[:-1], cuts[1:]))


def _row_costs(passes, shape) -> np.ndarray:
    """Per row of the box the blur work of :meth:`Scatter._band` (kernel taps × columns)."""
    cost = np.ones(shape[0])
    for chans, _, ty, tx in passes:
        for terms in (ty, tx):
            if isinstance(terms, _Taps):
                cost += len(chans) * (3 * terms.radius + 5) * shape[1]
                continue
            for s, _, (y0, y1, x0, x1) in terms:
                cost[y0:y1] += len(chans) * (gaussian_kernel(s).size + 4) * (x1 - x0)
    return cost


def _accumulate(total, blurred, wt, buf):
    """total + wt · blurred in place (the first term, total None: wt · blurred into ``buf``;
    numpy's float32 product, the bytes of cv2.multiply's by a scalar at ~1/6 of its time)."""
    import cv2

    if total is None:
        return np.multiply(blurred, np.float32(wt), out=buf)
    return cv2.scaleAdd(blurred, float(wt), total, dst=total)


def _take_work(n: int) -> list[_Work]:
    """A set of ``n`` buffer sets (a spare one when there is, its buffers already paged in)."""
    with _SCATTERS_LOCK:
        got = _SPARE.pop() if _SPARE else []
    return got[:n] + [_Work() for _ in range(n - len(got))]


def _give_work(works: list[_Work]) -> None:
    """Keep ``works`` for the next call (at most two sets: calls rarely overlap)."""
    with _SCATTERS_LOCK:
        if len(_SPARE) < 2:
            _SPARE.append(works)


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


def _near_uniform(step: np.ndarray) -> bool:
    """Whether a (positive) step map's values lie within NEAR_UNIFORM of each other."""
    return bool(step.size) and float(step.max()) <= NEAR_UNIFORM * float(step.min())


def _mean_step(step: np.ndarray) -> float:
    """The geometric mean of a step map's extremes (the value itself when it is uniform)."""
    lo, hi = float(step.min()), float(step.max())
    return lo if lo == hi else float(np.sqrt(lo * hi))


__all__ = ["SKIN_PROFILE", "Scatter", "fold_faint", "sss_blur", "sss_blur_plane"]
