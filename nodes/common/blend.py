"""Image blending for compositing: a feathered alpha, a smooth fill of a field known on part of
the image (normalized convolution, extended outward), Laplacian-pyramid (multi-band) blending, and
OpenCV's Poisson ``seamlessClone`` for comparison.  All float32/float64 H×W(×C) arrays.
"""
from __future__ import annotations

import numpy as np


def feather(mask: np.ndarray, width: float) -> np.ndarray:
    """Alpha rising from 0 at ``mask``'s border to 1 at ``width`` pixels inside it (smoothstep
    of the Euclidean distance to the nearest pixel outside), 0 outside."""
    from scipy.ndimage import distance_transform_edt

    mask = np.asarray(mask)
    out = np.zeros(mask.shape, np.float32)
    box = bounding_box(mask, pad=1)
    if box is None:
        return out
    # (the nearest pixel outside is never beyond the box a pixel wider than the mask: the
    # same distances as over the whole image, for a face's share of a 12-megapixel photo)
    t = np.clip(distance_transform_edt(mask[box]) / max(width, 1e-6), 0.0, 1.0)
    out[box] = t * t * (3.0 - 2.0 * t)
    return out


def bounding_box(mask: np.ndarray, pad: int = 0) -> tuple[slice, slice] | None:
    """The rows and columns holding ``mask``'s set pixels, ``pad`` wider each way (within the
    image), or None when none is set."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if rows.size == 0:
        return None
    h, w = mask.shape[:2]
    return (slice(max(int(rows[0]) - pad, 0), min(int(rows[-1]) + 1 + pad, h)),
            slice(max(int(cols[0]) - pad, 0), min(int(cols[-1]) + 1 + pad, w)))


def _pyramid_sizes(h: int, w: int) -> list[tuple[int, int]]:
    """The sizes of a Gaussian pyramid's levels (OpenCV's pyrDown rounding), down to 1 px."""
    sizes = [(h, w)]
    while min(sizes[-1]) > 1:
        sh, sw = sizes[-1]
        sizes.append(((sh + 1) // 2, (sw + 1) // 2))
    return sizes


def _blur(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur (:func:`nodes.common.filters.gaussian_blur`: the same bytes on every CPU);
    a wide one on an image shrunk so that σ is 4 px there, then enlarged."""
    import cv2

    from .filters import gaussian_blur

    f = max(1, int(sigma // 4))
    if f == 1:
        return gaussian_blur(x, sigma).reshape(x.shape)
    h, w = x.shape[:2]
    small = cv2.resize(x, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    small = gaussian_blur(small, sigma / f)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR).reshape(x.shape)


class SmoothFill:
    """:func:`smooth_fill` for one ``weight`` and ``scale_px`` (on a grid where σ is at least
    ``grid_sigma`` pixels): what depends only on them (the
    blurred weights, the supported region, each pixel's nearest supported pixel, the blend
    weights of the outward blurs) is prepared once, and calling it with values fills them
    (a new light on the same face and photo: CompositeFace)."""

    def __init__(self, weight: np.ndarray, scale_px: float, grid_sigma: float = 4.0):
        import cv2
        from scipy.ndimage import distance_transform_edt

        w = np.clip(np.asarray(weight, np.float32), 0.0, 1.0)
        if not (w > 0).any():
            raise ValueError("smooth_fill: no pixel has weight")
        s = max(float(scale_px), 0.5)
        # the field is smooth at σ = s: it is computed on a grid f times coarser (σ ≥ grid_sigma
        # px there) and enlarged bilinearly
        self.f = f = max(1, int(s // grid_sigma))
        self.shape = w.shape
        self.small = (max(1, w.shape[1] // f), max(1, w.shape[0] // f))
        ws = w if f == 1 else cv2.resize(w, self.small, interpolation=cv2.INTER_AREA)
        s = s / f
        den = _blur(ws, s)
        known = den >= 0.5 * den.max()
        dist, (iy, ix) = distance_transform_edt(~known, return_indices=True)
        level = np.log2(1.0 + dist / s)  # 0 at the supported region, +1 each time the distance doubles
        self.w, self.s = w, s
        self.near = (iy * iy.shape[1] + ix).ravel()  # each pixel's nearest supported pixel (flat)
        self.den = np.maximum(den, 1e-12)[:, :, None]
        # σ = s·2^k takes over from σ/2 along level k−1…k: each pixel is the blur at σ·2^⌈level⌉,
        # blended with the one at half that σ where the level is not whole.  Per step k: the
        # pixels it gives whole (level = k) and those it blends in (k − 1 < level < k: their
        # flat indices and weights)
        self.steps = []
        flat_level = level.ravel()
        for k in range(int(np.ceil(level.max())) + 1):
            a = np.clip(flat_level - (k - 1), 0.0, 1.0)
            part = np.flatnonzero((a > 0) & (a < 1))
            self.steps.append((np.flatnonzero(flat_level == k), part, a[part][:, None]))

    def __call__(self, values: np.ndarray, box: tuple[slice, slice] | None = None) -> np.ndarray:
        """The filled field of ``values``: the whole image's, or with ``box`` (row and column
        slices) the values in that box, 0 everywhere else (the same result, without the
        product of the weights and the zeros outside it)."""
        import cv2

        v = np.asarray(values, np.float32)
        squeeze = v.ndim == 2
        v = v[:, :, None] if squeeze else v
        if box is None:
            vw = v * self.w[:, :, None]
        else:
            vw = np.zeros(self.shape + v.shape[2:], np.float32)
            vw[box] = v * self.w[box][:, :, None]
        if self.f > 1:
            vw = cv2.resize(vw, self.small, interpolation=cv2.INTER_AREA).reshape(self.small[1], self.small[0], -1)
        num = _blur(vw, self.s)
        est = num / self.den
        c = est.shape[2]
        ext = est.reshape(-1, c)[self.near].reshape(est.shape)
        out = np.empty(ext.shape, np.float64)
        flat = out.reshape(-1, c)
        prev = None
        for k, (whole, part, a) in enumerate(self.steps):  # blur·a + the previous blur·(1 − a)
            b = _blur(ext, self.s * 2.0 ** k).reshape(-1, c)
            flat[whole] = b[whole]
            flat[part] = prev[part] * (1.0 - a) + b[part] * a if len(part) else 0.0
            prev = b
        if self.f > 1:
            h, w = self.shape
            out = cv2.resize(out.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR).reshape(h, w, -1)
        return out[:, :, 0] if squeeze else out


def smooth_fill(values: np.ndarray, weight: np.ndarray, scale_px: float) -> np.ndarray:
    """A smooth field that follows ``values`` where ``weight`` (in [0, 1]) is high, at the
    resolution of ``scale_px`` pixels, and extends them outward everywhere else.

    Normalized convolution (Knutsson & Westin 1993) at σ = ``scale_px`` gives the field where
    the weights support it (their blurred sum ≥ ½); every other pixel takes the value of the
    nearest supported pixel, blurred more the farther it is from them (σ doubling with the
    distance, so the ridges between regions that extend different values stay smooth): the
    field keeps its value at the border and carries it outward, it does not relax towards the
    mean of the whole region nor extrapolate a slope.  (:class:`SmoothFill` keeps the work
    that depends on the weights only, for several fields.)"""
    return SmoothFill(weight, scale_px)(values)


def laplacian_blend(a: np.ndarray, b: np.ndarray, alpha: np.ndarray, levels: int | None = None) -> np.ndarray:
    """Multi-band blend (Burt & Adelson 1983): ``alpha``·a + (1 − alpha)·b band by band, each
    band's alpha the Gaussian pyramid of ``alpha`` at that level, so low frequencies mix over
    wide regions and fine detail over a narrow one.  ``levels`` default: down to ~16 px."""
    import cv2

    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    al = np.asarray(alpha, np.float32)
    sizes = _pyramid_sizes(*al.shape)
    n = levels if levels is not None else max(1, sum(1 for s in sizes if min(s) >= 16))
    sizes = sizes[:n]
    ga, gb, gm = [a], [b], [al]
    for h, w in sizes[1:]:
        ga.append(cv2.pyrDown(ga[-1], dstsize=(w, h)).reshape(h, w, -1))
        gb.append(cv2.pyrDown(gb[-1], dstsize=(w, h)).reshape(h, w, -1))
        gm.append(cv2.pyrDown(gm[-1], dstsize=(w, h)))
    out = ga[-1] * gm[-1][:, :, None] + gb[-1] * (1.0 - gm[-1][:, :, None])
    for k in range(len(sizes) - 2, -1, -1):
        h, w = sizes[k]

        def band(g):
            return g[k] - cv2.pyrUp(g[k + 1], dstsize=(w, h)).reshape(h, w, -1)

        m = gm[k][:, :, None]
        out = cv2.pyrUp(out, dstsize=(w, h)).reshape(h, w, -1) + band(ga) * m + band(gb) * (1.0 - m)
    return out.reshape(a.shape)


def seamless_clone(src: np.ndarray, dst: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """OpenCV's Poisson cloning (``cv2.seamlessClone``, NORMAL_CLONE) of ``src`` into ``dst``
    where ``mask``; linear RGB in [0, 1] in and out, through 8-bit sRGB (the only depth
    OpenCV clones), so the result carries 8-bit quantisation everywhere."""
    import cv2

    from .color import linear_to_codes, srgb_codes_to_linear

    def enc(x):
        return linear_to_codes(np.clip(x, 0, 1))

    m = (np.asarray(mask) > 0).astype(np.uint8) * 255
    m[0, :] = m[-1, :] = m[:, 0] = m[:, -1] = 0  # OpenCV needs a border around the mask
    ys, xs = np.nonzero(m)
    if len(ys) == 0:
        return np.asarray(dst, np.float32)
    y0, y1, x0, x1 = ys.min(), ys.max(), xs.min(), xs.max()
    centre = (int(x0 + (x1 - x0 + 1) // 2), int(y0 + (y1 - y0 + 1) // 2))  # OpenCV's rect centre
    out = cv2.seamlessClone(enc(src), enc(dst), m, centre, cv2.NORMAL_CLONE)
    return srgb_codes_to_linear(out)
