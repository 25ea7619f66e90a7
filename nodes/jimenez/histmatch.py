"""Approximate local histogram matching and the appearance rig (Jimenez 2010 §4.1, §4.2).

Local statistics under a disc of radius r (eq. 1) are computed two ways, with the same border
and mask rules (statistics of the in-image, in-mask part of the disc: μ = (H·M ∗ f)/(M ∗ f)):

- exact (:func:`local_mean_std`): FFT convolution at full resolution (scipy.fft; float32 on
  mean-centred data, float64 with a mask); equals ``cv2.filter2D`` with the normalised disc
  kernel on the interior (tests/oracles).  Cost per pixel O(log N), whatever r.
- fast (:func:`grid_mean_std`, the default): the paper stores μ, σ, scale and bias
  downsampled because they are low-frequency (§4.2, §6).  The moments H, H² (and the mask) are
  summed over cells of c = ⌊r/4⌋ pixels, the disc sum is taken on that grid with the exact
  cell-coverage kernel of the disc (≤ 13 × 13 taps), and eq. (3) is applied with scale and bias
  resized bilinearly.  Cost per pixel: a fixed number of passes over the maps plus
  ≤ 169/c² taps (c ≥ 2), so it does not grow with r (it falls).  The disc edge is resolved to about one
  cell: mean |Δ| ≈ 1.5% of σ from the exact path at r = 16 on white noise (falling as 1/r),
  1.2–1.8% on the astronaut's hemoglobin maps (tests/oracles/test_jimenez_histmatch.py).  Below r = 8 px
  and in the global limit (r beyond the image diagonal) it is the exact path.
"""
from __future__ import annotations

import functools
from typing import Literal

import numpy as np

from graphkit import BadInput, Field, Image, In, Mask, Node, Out

# --------------------------------------------------------------------------------------------
# maths


def disc_kernel(r: float) -> np.ndarray:
    """(2R+1)² float64 indicator of the disc dx² + dy² ≤ r² (R = ⌊r⌋); not normalised."""
    R = int(np.floor(r))
    y, x = np.mgrid[-R:R + 1, -R:R + 1]
    return (x * x + y * y <= r * r).astype(np.float64)


@functools.lru_cache(maxsize=8)
def _kernel_fft(r: float, ph: int, pw: int, dtype: str = "float32") -> np.ndarray:
    import scipy.fft as sf

    R = int(np.floor(r))
    k = np.zeros((ph, pw), dtype)
    y, x = np.nonzero(disc_kernel(r))
    k[(y - R) % ph, (x - R) % pw] = 1.0
    f = sf.rfft2(k, workers=-1)
    f.setflags(write=False)
    return f


def fft_shape(H: int, W: int, r: float) -> tuple[int, int]:
    """FFT size per axis: ≥ N + ⌊r⌋ (only the central N outputs are kept, so wrap-around of
    the kernel's far side lands in the discarded part)."""
    import scipy.fft as sf

    R = int(np.floor(r))
    return sf.next_fast_len(H + R, real=True), sf.next_fast_len(W + R, real=True)


def disc_sums(maps: np.ndarray, r: float, workers: int | None = -1, dtype=np.float32) -> np.ndarray:
    """Sums of each (…, H, W) map over the disc of radius r (pixels) around every pixel.

    Pixels outside the image count as 0.  Linear convolution by FFT (``scipy.fft``) in
    ``dtype`` (float32 by default: callers centre their data so that the round-off stays
    ~1e-7 of the data's spread).
    """
    import scipy.fft as sf

    maps = np.asarray(maps, dtype)
    H, W = maps.shape[-2:]
    ph, pw = fft_shape(H, W, r)
    fm = sf.rfft2(maps, s=(ph, pw), workers=workers)
    fm *= _kernel_fft(float(r), ph, pw, np.dtype(dtype).name)
    return sf.irfft2(fm, s=(ph, pw), workers=workers)[..., :H, :W]


def disc_counts(H: int, W: int, r: float) -> np.ndarray:
    """Exact number of image pixels under the disc around every pixel (float64).

    count(y, x) = Σ_dy [0 ≤ y+dy < H] · |[x − w(dy), x + w(dy)] ∩ [0, W)|, w(dy) = ⌊√(r² − dy²)⌋,
    evaluated as one (H × (2R+1)) @ ((2R+1) × W) matrix product.
    """
    R = int(np.floor(r))
    dy = np.arange(-R, R + 1)
    hw = np.floor(np.sqrt(np.maximum(r * r - dy * dy, 0.0)) + 1e-9).astype(np.int64)
    y = np.arange(H)[:, None]
    A = ((y + dy[None, :] >= 0) & (y + dy[None, :] < H)).astype(np.float64)
    x = np.arange(W)[None, :]
    G = np.minimum(x + hw[:, None], W - 1) - np.maximum(x - hw[:, None], 0) + 1
    return A @ np.maximum(G, 0).astype(np.float64)


@functools.lru_cache(maxsize=4)
def _inverse_counts(H: int, W: int, r: float) -> tuple[np.ndarray, np.ndarray]:
    cnt = disc_counts(H, W, r)
    inv = (1.0 / cnt).astype(np.float32)
    cnt.setflags(write=False)
    inv.setflags(write=False)
    return cnt, inv


def _mean_std(e1: np.ndarray, e2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(μ, σ) from the disc means e1 = E[h], e2 = E[h²] (of centred data): σ = √max(e2 − μ², 0).
    Overwrites e2 with σ."""
    e2 -= e1 * e1
    np.maximum(e2, 0.0, out=e2)
    return e1, np.sqrt(e2, out=e2)


def local_mean_std(h: np.ndarray, r: float, mask: np.ndarray | None = None,
                   workers: int | None = -1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (1): local mean μ and standard deviation σ of ``h`` under a disc of radius r px.

    Only pixels inside the image (weighted by ``mask`` when given) enter the statistics:
    μ = (h·m ∗ f)/(m ∗ f), σ² = (h²·m ∗ f)/(m ∗ f) − μ².  Returns (μ, σ, weight) where weight is
    the mask mass under the disc (0: statistics undefined there).  ``h`` may be (H, W) or
    (n, H, W) (n maps sharing the mask, transformed in one batch).  Each map is centred on its
    (masked) mean before the FFT, so σ² suffers no cancellation.  Without a mask the work and
    the results are float32 (≈1e-7 relative); with a mask float64 (few pixels may fall under
    a disc there).
    """
    h = np.asarray(h)
    if h.dtype not in (np.float32, np.float64):
        h = h.astype(np.float64)
    single = h.ndim == 2
    hs = h[None] if single else h
    n, H, W = hs.shape
    m = None if mask is None else np.asarray(mask, np.float64)
    msum = float(H * W) if m is None else float(m.sum())
    c = np.array([(x.sum() if m is None else (x * m).sum()) / max(msum, 1e-300) for x in hs])
    if r * r >= (H - 1) ** 2 + (W - 1) ** 2:  # the disc covers the whole image from everywhere
        wsum = np.full((H, W), msum)
        mu = np.empty((n, H, W))
        sd = np.empty((n, H, W))
        for i, x in enumerate(hs):
            d = x - c[i]
            var = (d * d).sum() / msum if m is None else (d * d * m).sum() / msum
            mu[i] = c[i]
            sd[i] = np.sqrt(var)
        return (mu[0], sd[0], wsum) if single else (mu, sd, wsum)
    k = 2 * n + (0 if m is None else 1)
    # with a mask, few pixels may fall under the disc: divide by small counts in float64
    dt = np.float32 if m is None else np.float64
    stack = np.empty((k, H, W), dt)
    m32 = None if m is None else m.astype(dt)
    for i, x in enumerate(hs):
        d = stack[i]
        np.subtract(x, c[i], out=d, casting="same_kind")
        np.multiply(d, d, out=stack[n + i])
        if m32 is not None:
            d *= m32
            stack[n + i] *= m32
    if m32 is not None:
        stack[-1] = m32
    sums = disc_sums(stack, r, workers, dt)
    if m is None:  # every disc holds ≥ 1 image pixel: float32 all the way
        cnt, inv = _inverse_counts(H, W, float(r))
        mu = sums[:n]
        mu *= inv
        var = sums[n:2 * n]
        var *= inv
        mu, sd = _mean_std(mu, var)
        mu += c[:, None, None].astype(np.float32)
        wsum = cnt
    else:
        wsum = sums[-1]
        ok = wsum > 1e-6 * max(float(wsum.max()), 1e-300)
        inv = 1.0 / np.where(ok, wsum, 1.0)
        mu_d, sd = _mean_std(sums[:n] * inv, sums[n:2 * n] * inv)
        mu = mu_d + c[:, None, None]
        wsum = np.where(ok, wsum, 0.0)
    return (mu[0], sd[0], wsum) if single else (mu, sd, wsum)


# --------------------------------------------------------------------------------------------
# fast path: statistics on a reduced grid (§4.2, §6: μ, σ, scale and bias are low-frequency)

#: grid cells per disc radius in the fast path: the cell size is chosen from r so that the
#: disc always spans about this many cells (the cost per pixel is then constant in r)
CELLS_PER_RADIUS = 4


def stats_cell(H: int, W: int, r: float, cells: int = CELLS_PER_RADIUS) -> int:
    """Cell size (pixels, an integer) of the fast path's statistics grid: ⌊r/cells⌋, or 1 (the
    full size, i.e. the exact statistics) where that is < 2 or where the disc covers the
    whole image from every pixel (the global limit)."""
    if r * r >= (H - 1) ** 2 + (W - 1) ** 2:
        return 1
    c = int(np.floor(r / cells))
    return c if c >= 2 else 1


@functools.lru_cache(maxsize=16)
def grid_disc_kernel(r: float, c: int, sub: int = 16) -> np.ndarray:
    """Disc of radius r pixels over c × c-pixel cells: w(i, j) = area fraction of the cell
    centred on the offset (i·c, j·c) px that lies inside the disc (sub² point samples per
    cell), float32.  Filtering per-cell mean maps with it gives the disc sums (/c²) of maps
    that are constant within cells."""
    R = int(np.floor(r / c + 0.5))  # cells whose near edge is inside the disc
    t = (np.arange(sub) + 0.5) / sub - 0.5
    y = (np.arange(-R, R + 1)[:, None] + t[None, :]).ravel() * c  # ((2R+1)·sub,) sample offsets
    inside = (y[:, None] ** 2 + y[None, :] ** 2 <= r * r).astype(np.float64)
    k = inside.reshape(2 * R + 1, sub, 2 * R + 1, sub).mean(axis=(1, 3)).astype(np.float32)
    k.setflags(write=False)
    return k


def cell_means(x: np.ndarray, c: int) -> np.ndarray:
    """(⌈H/c⌉, ⌈W/c⌉) float32 map of the sums of ``x`` over c × c-pixel cells divided by c²
    (the cell mean, times the in-image fraction of the cell for the last row and column).
    Whole cells by ``cv2.resize`` INTER_AREA with an integer factor (one pass, its fast path)."""
    import cv2

    H, W = x.shape
    qH, qW = H // c, W // c
    out = np.zeros((-(-H // c), -(-W // c)), np.float32)
    if qH and qW:
        whole = x[:qH * c, :qW * c]
        if c % 2 == 0:  # halving first is cv2's fastest area path (≈2× less time at 2048²)
            whole = cv2.resize(whole, (qW * c // 2, qH * c // 2), interpolation=cv2.INTER_AREA)
        out[:qH, :qW] = cv2.resize(whole, (qW, qH), interpolation=cv2.INTER_AREA)
    inv = 1.0 / (c * c)
    if H > qH * c and qW:
        out[qH, :qW] = x[qH * c:, :qW * c].reshape(H - qH * c, qW, c).sum((0, 2), dtype=np.float64) * inv
    if W > qW * c and qH:
        out[:qH, qW] = x[:qH * c, qW * c:].reshape(qH, c, W - qW * c).sum((1, 2), dtype=np.float64) * inv
    if H > qH * c and W > qW * c:
        out[qH, qW] = x[qH * c:, qW * c:].sum(dtype=np.float64) * inv
    return out


def cell_fraction(H: int, W: int, c: int) -> np.ndarray:
    """In-image fraction of each c × c cell (= :func:`cell_means` of ones), float32."""
    fy = np.minimum(H - c * np.arange(-(-H // c)), c) / c
    fx = np.minimum(W - c * np.arange(-(-W // c)), c) / c
    return np.outer(fy, fx).astype(np.float32)


def _cell_moments(h: np.ndarray, m: np.ndarray | None, c: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cell_means` of h·m and h²·m, in one pass over bands of ≥ 256 rows on the cores
    (the band's h·m and h²·m stay in the cache)."""
    import cv2

    from nodes.common.parallel import run_bands

    H, W = h.shape
    a1 = np.empty((-(-H // c), -(-W // c)), np.float32)
    a2 = np.empty_like(a1)
    rows = c * max(1, 256 // c)

    def band(y0, _y1):
        hb = h[y0:y0 + rows]
        x = hb if m is None else cv2.multiply(hb, m[y0:y0 + rows])
        a1[y0 // c:y0 // c + -(-hb.shape[0] // c)] = cell_means(x, c)
        a2[y0 // c:y0 // c + -(-hb.shape[0] // c)] = cell_means(cv2.multiply(x, hb), c)

    run_bands(band, H, rows)
    return a1, a2


def grid_mean_std(hs, r: float, mask: np.ndarray | None = None, cells: int = CELLS_PER_RADIUS,
                  moments=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fast eq. (1): local mean and standard deviation of each (H, W) map in ``hs`` (a sequence
    or an (n, H, W) array) on the grid of c × c-pixel cells, c = :func:`stats_cell`, returned
    as (μ, σ, weight), each (n, ⌈H/c⌉, ⌈W/c⌉), values at the cell centres (see
    :func:`grid_resize` for other resolutions); weight is the mask mass under the disc in
    pixels (0: statistics undefined there).

    The moments h·m, h²·m and m are summed over the cells (:func:`cell_means`, O(1) per pixel),
    then over the disc with the cell-coverage kernel of :func:`grid_disc_kernel`
    (``cv2.filter2D``: ≤ (2·⌊cells + cells/c + ½⌋ + 1)² ≤ 13² taps on H·W/c² cells, so the work per image pixel falls
    with r).  This is exact for maps that are constant within cells; otherwise the disc edge is
    blurred over about one cell (r/cells px).  Border and mask handling as in
    :func:`local_mean_std` (statistics of the in-image, in-mask part of the disc).  float32 on
    data centred on its global mean.  Where c = 1 this is :func:`local_mean_std` (exact).
    ``moments``: the function that takes the per-cell
    moments (default :func:`_cell_moments`; a backend passes its own).
    """
    import cv2

    n = len(hs)
    H, W = hs[0].shape
    c = stats_cell(H, W, r, cells)
    if c == 1:
        return local_mean_std(hs if isinstance(hs, np.ndarray) else np.stack(hs), r, mask)
    k = grid_disc_kernel(float(r), c)
    if mask is None:
        m = None
        am, inv, weight = _grid_weights(H, W, float(r), c)
    else:
        m = np.ascontiguousarray(mask, np.float32)
        am = cell_means(m, c)
        inv, weight = _disc_weights(am, k, c)
    msum = float(am.sum(dtype=np.float64))
    full = m is None and H % c == 0 and W % c == 0  # am = 1 everywhere
    mom = []  # centred (E[h·m], E[h²·m]) per map
    g = np.empty(n)
    for i in range(n):
        a1, a2 = (moments or _cell_moments)(np.ascontiguousarray(hs[i], np.float32), m, c)
        # centre on the (masked) global mean g: E[(h−g)²m] = E[h²m] − 2g·E[hm] + g²·E[m]
        g[i] = gi = float(a1.sum(dtype=np.float64)) / max(msum, 1e-300)
        if full:
            mom += [cv2.addWeighted(a1, 1.0, a1, 0.0, -gi), cv2.addWeighted(a2, 1.0, a1, -2.0 * gi, gi * gi)]
        else:
            mom += [cv2.scaleAdd(am, -gi, a1), cv2.scaleAdd(am, gi * gi, cv2.addWeighted(a2, 1.0, a1, -2.0 * gi, 0.0))]
    e = _disc_filter(mom, k)
    e *= inv
    mu, sd = _mean_std(e[0::2], e[1::2])
    mu += g[:, None, None].astype(np.float32)
    return mu, sd, weight


def _disc_weights(am: np.ndarray, k: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
    """1 / (disc sum of the cell weights ``am``) (1 where that is ~0) and the weight output of
    :func:`grid_mean_std` (the mask mass under the disc in pixels, 0 where undefined)."""
    wsum = _disc_filter([am], k)[0]
    ok = wsum > 1e-6 * float(k.sum())
    return np.float32(1.0) / np.where(ok, wsum, np.float32(1.0)), np.where(ok, wsum * np.float32(c * c), np.float32(0.0))


def _disc_filter(maps: list[np.ndarray], k: np.ndarray) -> np.ndarray:
    """Correlate float32 (gH, gW) grids with the cell-coverage kernel ``k``, zero outside
    (``cv2.filter2D`` on up to 4 maps merged as channels per call); returns (n, gH, gW)."""
    import cv2

    out = np.empty((len(maps),) + maps[0].shape, np.float32)
    for i in range(0, len(maps), 4):
        group = maps[i:i + 4]
        f = cv2.filter2D(cv2.merge(group) if len(group) > 1 else group[0], -1, k,
                         borderType=cv2.BORDER_CONSTANT)
        out[i:i + len(group)] = np.moveaxis(f.reshape(f.shape[:2] + (-1,)), -1, 0)
    return out


@functools.lru_cache(maxsize=8)
def _grid_weights(H: int, W: int, r: float, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Without a mask: the in-image fraction of each cell and its :func:`_disc_weights`."""
    am = cell_fraction(H, W, c)
    out = (am,) + _disc_weights(am, grid_disc_kernel(r, c), c)
    for a in out:
        a.setflags(write=False)
    return out


def _regrid(a: np.ndarray, n: int, c: int, axis: int) -> np.ndarray:
    """Linear interpolation along ``axis`` from g cells of c px (the last one sticking out of
    the n-pixel image) to g cells of n/g px tiling it exactly."""
    g = a.shape[axis]
    if g * c == n or g == 1:
        return a
    u = (np.arange(g) + 0.5) * (n / g) / c - 0.5
    j = np.clip(np.floor(u).astype(np.int64), 0, g - 2)
    f = np.clip(u - j, 0.0, 1.0).astype(np.float32)
    shape = (-1, 1) if axis == 0 else (1, -1)
    return np.take(a, j, axis) * (1 - f).reshape(shape) + np.take(a, j + 1, axis) * f.reshape(shape)


def grid_resize(a: np.ndarray, c: int, image_shape: tuple[int, int],
                shape: tuple[int, int] | None = None) -> np.ndarray:
    """Resample a statistics map ``a`` on the grid of c × c-pixel cells (:func:`grid_mean_std`;
    c = 1: a full-size map) onto the image of ``image_shape``, or onto ``shape`` covering the
    same image: bilinear with the cell centres at (i + ½)·c px (:func:`resize_to`; where the
    last cells stick out of the image the grid is first interpolated onto cells tiling it)."""
    H, W = image_shape
    if c > 1:
        a = _regrid(_regrid(np.asarray(a, np.float32), H, c, 0), W, c, 1)
    return resize_to(a, image_shape if shape is None else shape)


def apply_scale_bias(hn: np.ndarray, scale: np.ndarray, mu: np.ndarray, mu_n: np.ndarray,
                     c: int = 1) -> np.ndarray:
    """Eq. (3) as an affine map of H_n: H = a·H_n + b, a = σ/σ_n, b = μ − a·μ_n, with (a, b) given
    on the grid of c-pixel cells (c = 1: full size) and resized bilinearly to H_n's
    (:func:`grid_resize`; the statistics are low-frequency, §6), then H clipped at 0.  float32
    ``cv2`` operations on bands of rows that stay in the cache: a, b are never stored at full
    size (bit-identical to resizing them whole)."""
    import cv2

    a = np.ascontiguousarray(scale, np.float32)
    b = np.ascontiguousarray(np.asarray(mu, np.float32) - a * np.asarray(mu_n, np.float32))
    hn = np.ascontiguousarray(hn, np.float32)
    H, W = hn.shape
    gH, gW = a.shape
    if c > 1 and (gH * c, gW * c) != (H, W):  # cells sticking out of the image: resize whole
        a, b = grid_resize(a, c, (H, W)), grid_resize(b, c, (H, W))
        c, gH, gW = 1, H, W
    out = np.empty((H, W), np.float32)
    # bands of whole cells, ≥ 8 cells and ≥ 256 rows: a, b of a band stay in the cache
    band = H if c == 1 else c * max(8, 256 // c)
    for y0 in range(0, H, band):
        y1 = min(y0 + band, H)
        if c == 1:
            ab, bb = a[y0:y1], b[y0:y1].copy()
        else:  # cells j0…j1 with one cell of margin: inside it cv2's bilinear weights are those of
            #     the whole resize (same source rows, same fractions: exact scale c)
            j0, j1 = max(y0 // c - 1, 0), min(y1 // c + 1, gH)
            off = y0 - j0 * c
            ab = cv2.resize(a[j0:j1], (W, (j1 - j0) * c), interpolation=cv2.INTER_LINEAR)[off:off + y1 - y0]
            bb = cv2.resize(b[j0:j1], (W, (j1 - j0) * c), interpolation=cv2.INTER_LINEAR)[off:off + y1 - y0]
        cv2.accumulateProduct(hn[y0:y1], ab, bb)  # b += H_n·a
        cv2.threshold(bb, 0.0, 0.0, cv2.THRESH_TOZERO, dst=out[y0:y1])
    return out


def resize_to(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear resize of a 2-D map to (H, W) (cv2, pixel-centre aligned)."""
    import cv2

    a = np.asarray(a)
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    if a.shape[:2] == tuple(shape):
        return a
    interp = cv2.INTER_AREA if a.shape[0] > shape[0] else cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(a), (shape[1], shape[0]), interpolation=interp)


def stats_shape(shape: tuple[int, int], size: int) -> tuple[int, int]:
    """Longer side → ``size`` (0: keep), keeping the aspect ratio."""
    H, W = shape
    if size <= 0 or max(H, W) <= size:
        return H, W
    s = size / max(H, W)
    return max(1, round(H * s)), max(1, round(W * s))


def _mask(mask: Mask | None, port="mask") -> np.ndarray | None:
    """The mask's weights in [0, 1] (its size is declared on the port); BadInput if all zero."""
    if mask is None:
        return None
    m = np.clip(mask.alpha.astype(np.float64), 0, 1)
    if m.sum() <= 0:
        raise BadInput(port, "the mask is empty: no skin to take statistics from")
    return m


# --------------------------------------------------------------------------------------------
# nodes


class LocalHistMatch(Node):
    """Approximate local histogram matching (Jimenez 2010 §4.1 eqs. 1–3, §4.2 eq. 5).

    Local Gaussian statistics (μ, σ) of the neutral map H_n and of the target map H under a
    disc of radius ``radius`` pixels (eq. 1; f = disc / its area), then eq. (3)
    H = μ + σ/σ_n (H_n − μ_n).  Outputs the matched map (clipped at 0: concentrations are
    volume fractions ≥ 0) and the eq. (5) parameters of this basis entry: ``scale`` = σ/σ_n,
    ``bias`` = μ, plus ``neutral_mean`` = μ_n (for H_0 = H_n − μ_n, eq. 4), all resized to
    ``stats_size`` on the longer side (the paper stores them at 256²).  Maps are
    dimensionless hemoglobin (or melanin) volume fractions; ``radius`` is in pixels.

    ``mode``: ``fast`` (default) takes the statistics on a grid of ⌊r/4⌋-pixel cells and
    applies eq. (3) with them resized bilinearly (§6); ``exact`` convolves at full resolution
    (FFT).  Cost per pixel does not grow with r in either mode (fast: constant passes plus
    ≤ 169/c² grid taps per pixel, c = ⌊r/4⌋ ≥ 2; exact: O(log N)); r beyond the image diagonal = global match.
    """

    version = "5"
    inputs = {"neutral": In(Image, "neutral map H_n (volume fraction)", channels=1, finite=True, ge=0),
              "target": In(Image, "target map H", channels=1, same_size_as="neutral", finite=True, ge=0),
              "mask": In(Mask, "where statistics are taken (skin)", optional=True, same_size_as="neutral")}
    outputs = {"matched": Out(Image, "H_n matched to the target's local statistics (eq. 3)"),
               "scale": Out(Image, "σ/σ_n (eq. 5), at stats_size"),
               "bias": Out(Image, "μ (eq. 5), at stats_size"),
               "neutral_mean": Out(Image, "μ_n (eq. 4), at stats_size")}
    tolerance = {"rtol": 1e-4, "atol": 1e-5}
    # the per-pixel passes of the fast path, as hooks a backend replaces (plugins/graphkit-opencl)
    hooks = ("cell_moments", "apply_scale_bias")
    cell_moments = staticmethod(_cell_moments)
    apply_scale_bias = staticmethod(apply_scale_bias)

    class Params(Node.Params):
        radius: float = Field(16.0, description="disc radius r in pixels (> 0)")
        stats_size: int = Field(256, ge=0, description="longer side of the scale/bias maps (0 = full size)")
        eps: float = Field(1e-6, gt=0, description="floor of σ_n (volume fraction); below it scale = 1")
        mode: Literal["fast", "exact"] = Field(
            "fast", description="fast: statistics on a grid of ⌊r/4⌋-pixel cells (cost per pixel falls "
                                "with r; ~1.5% of σ from exact at r = 16); exact: full-resolution FFT "
                                "disc convolution")

    def compute(self, neutral: Image, target: Image, mask: Mask | None = None):
        p = self.params
        if not p.radius > 0:
            raise BadInput("radius", f"radius must be > 0 pixels, got {p.radius}")
        hn, ht = neutral.pixels[:, :, 0], target.pixels[:, :, 0]
        m = _mask(mask)
        H, W = hn.shape
        with np.errstate(invalid="ignore", over="ignore"):  # huge values overflow the float32 moments
            if p.mode == "exact":
                c = 1
                (mu_n, mu), (sd_n, sd), w = local_mean_std(np.stack([hn, ht]), p.radius, m)
            else:
                c = stats_cell(H, W, p.radius)
                (mu_n, mu), (sd_n, sd), w = grid_mean_std([hn, ht], p.radius, m, moments=self.cell_moments)
        self.ctx.progress(0.8, "statistics done")
        # σ_n below the floor (a flat neighbourhood, or a one-pixel disc; without a mask 1e-3 of
        # the largest σ_n): H_n − μ_n is ~0 there, so the scale is 1 rather than a ratio of
        # round-off values
        floor = max(p.eps, 1e-3 * float(sd_n.max())) if m is None else p.eps
        scale = np.where(sd_n <= floor, 1.0, sd / np.maximum(sd_n, floor))
        if m is not None:  # no skin under the disc: statistics undefined, H = H_n there
            ok = w > 0
            hn_s = hn if c == 1 else cell_means(hn, c) / cell_fraction(H, W, c)
            scale = np.where(ok, scale, 1.0)
            mu = np.where(ok, mu, hn_s)
            mu_n = np.where(ok, mu_n, hn_s)
        out = self.apply_scale_bias(hn, scale, mu, mu_n, c)  # eq. (3)
        if m is not None:  # outside the skin: unchanged
            np.copyto(out, hn, where=m <= 0)
        shp = stats_shape(hn.shape, p.stats_size)

        def store(a):  # the eq. (5) maps at stats_size
            return Image(grid_resize(np.asarray(a, np.float32), c, (H, W), shp))

        # means of non-negative maps are ≥ 0; clip the round-off (~1e-7)
        return {"matched": Image(out), "scale": store(scale), "bias": store(np.maximum(mu, 0.0)),
                "neutral_mean": store(np.maximum(mu_n, 0.0))}

    @classmethod
    def examples(cls):
        rng = np.random.default_rng(5)
        a = Image(rng.random((40, 56, 1), dtype=np.float32) * 0.1)
        b = Image(rng.random((40, 56, 1), dtype=np.float32) * 0.2 + 0.05)
        # the fast grid path (r ≥ 8): whole cells, cells sticking out of the image, a mask
        yy, xx = np.mgrid[0:96, 0:128] / 64.0
        hn = (0.05 + 0.03 * np.sin(3 * xx) * np.cos(2 * yy))[..., None] + rng.random((96, 128, 1)) * 0.02
        ht = (0.08 + 0.05 * np.cos(4 * xx + yy))[..., None] + rng.random((96, 128, 1)) * 0.04
        skin = np.clip(1.5 - 2.0 * np.hypot(xx - 1.0, yy - 0.75), 0, 1)
        c, d = Image(hn.astype(np.float32)), Image(ht.astype(np.float32))
        c2, d2 = Image(c.pixels[:90, :125]), Image(d.pixels[:90, :125])
        return [({"radius": 5.0, "stats_size": 0}, {"neutral": a, "target": b}),
                ({"radius": 3.5, "stats_size": 20}, {"neutral": a, "target": b}),
                ({"radius": 16.0, "stats_size": 32}, {"neutral": c, "target": d}),
                ({"radius": 40.0, "stats_size": 0}, {"neutral": c, "target": d}),
                ({"radius": 16.0, "stats_size": 0}, {"neutral": c2, "target": d2, "mask": Mask(skin[:90, :125])})]


class AppearanceRig(Node):
    """Appearance rig (Jimenez 2010 §4.2, eqs. 4–6): H = Σ w_i bias_i + H_0 Σ w_i scale_i.

    ``neutral`` is H_n and ``neutral_mean`` μ_n (H_0 = H_n − μ_n, bias_0 = μ_n, scale_0 = 1);
    ``scales``/``biases`` are the basis entries i = 1…k from LocalHistMatch (any resolution:
    they are low-frequency and resized bilinearly, §6).  ``weights`` = [w_0, w_1, …, w_k] must
    sum to one.  ``hemoglobin_scale`` multiplies the result globally (the paper uses 1.27 for
    anger, 0.81 for fear).  Output: hemoglobin volume fraction map (clipped at 0).
    """

    version = "1"
    studio_view = "nodes.jimenez.studio_view:BlushView"  # graphkit serve: weight sliders
    inputs = {"neutral": In(Image, "neutral map H_n", channels=1, finite=True, ge=0),
              "neutral_mean": In(Image, "μ_n, local mean of H_n (any resolution)", channels=1, finite=True, ge=0),
              "scales": In(Image, "scale_i = σ_i/σ_n, i = 1…k", variadic=True, channels=1, ge=0),
              "biases": In(Image, "bias_i = μ_i, i = 1…k", variadic=True, channels=1, finite=True, ge=0)}
    outputs = {"hemoglobin": Out(Image, "rigged hemoglobin map H (eq. 6)")}

    class Params(Node.Params):
        weights: list[float] = Field(default_factory=lambda: [1.0],
                                     description="[w_0 (neutral), w_1 … w_k]; must sum to one")
        hemoglobin_scale: float = Field(1.0, ge=0, description="global factor (1.27 anger, 0.81 fear)")

    def compute(self, neutral: Image, neutral_mean: Image, scales: list[Image], biases: list[Image]):
        p = self.params
        if len(scales) != len(biases):
            raise BadInput("biases", f"{len(scales)} scale maps but {len(biases)} bias maps")
        if len(p.weights) != len(scales) + 1:
            raise BadInput("weights", f"{len(p.weights)} weights for {len(scales)} basis entries: "
                                      f"give {len(scales) + 1} ([w_0 for the neutral, then one per basis entry])")
        if abs(sum(p.weights) - 1.0) > 1e-6:
            raise BadInput("weights", f"weights must sum to one (eq. 6), they sum to {sum(p.weights):.6g}")
        hn = neutral.pixels[:, :, 0]
        shp = hn.shape
        mu_n = resize_to(neutral_mean.pixels[:, :, 0], shp)
        w0 = p.weights[0]
        bias = w0 * mu_n
        scale = np.full(shp, w0)
        for i, (s, b) in enumerate(zip(scales, biases), start=1):
            bias += p.weights[i] * resize_to(b.pixels[:, :, 0], shp)
            scale += p.weights[i] * resize_to(s.pixels[:, :, 0].astype(np.float64), shp)
        h = (bias + (hn - mu_n) * scale) * p.hemoglobin_scale
        return Image(np.maximum(h, 0.0).astype(np.float32))

    @classmethod
    def examples(cls):
        rng = np.random.default_rng(6)
        hn = Image(rng.random((30, 40, 1), dtype=np.float32) * 0.1)
        mu = Image(np.full((8, 10, 1), 0.05, np.float32))
        s = Image(rng.random((8, 10, 1), dtype=np.float32) + 0.5)
        b = Image(rng.random((8, 10, 1), dtype=np.float32) * 0.1)
        return [({"weights": [0.3, 0.7], "hemoglobin_scale": 1.27},
                 {"neutral": hn, "neutral_mean": mu, "scales": [s], "biases": [b]})]


class FlushTarget(Node):
    """An *example* flushed hemoglobin map for building a blush basis (not a measurement).

    H_flush = H_n · (1 + gain · g), with g the region mask (e.g. FaceMesh ``cheeks``) softened
    by a Gaussian of ``soften`` pixels and normalised to a peak of 1.  Scaling H_n keeps its
    vascular structure and raises both local mean and contrast, which is what the paper
    reports for blushing (§3.1 observations 2 and 4, §7).  Feed it with H_n to LocalHistMatch
    to get the basis statistics (eq. 5).  Unitless volume fractions.
    """

    version = "1"
    inputs = {"hemoglobin": In(Image, "neutral hemoglobin map H_n", channels=1, finite=True, ge=0),
              "regions": In(Mask, "where the flush goes (e.g. cheeks)", same_size_as="hemoglobin"),
              "extra": In(Mask, "a second region with half the gain (e.g. lips, nose)", optional=True,
                          same_size_as="hemoglobin")}
    outputs = {"hemoglobin": Out(Image, "example flushed map")}

    class Params(Node.Params):
        gain: float = Field(0.8, ge=0, description="relative hemoglobin increase at the centre of the region")
        soften: float = Field(12.0, ge=0, description="Gaussian σ of the region edges (pixels)")

    def compute(self, hemoglobin: Image, regions: Mask, extra: Mask | None = None):
        from scipy.ndimage import gaussian_filter

        hn = hemoglobin.pixels[:, :, 0]
        g = _mask(regions, "regions")
        if extra is not None:
            g = g + 0.5 * _mask(extra, "extra")
        g = gaussian_filter(g, self.params.soften) if self.params.soften > 0 else g
        g = g / max(g.max(), 1e-12)
        return Image((hn * (1.0 + self.params.gain * g)).astype(np.float32))
