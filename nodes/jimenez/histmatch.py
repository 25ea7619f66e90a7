"""Approximate local histogram matching and the appearance rig (Jimenez et al. 2010 §4.1, §4.2).

Local statistics under a disc of radius r (eq. 1) are computed with FFT convolution
(scipy.fft; float32 on mean-centred data, float64 with a mask): the cost per pixel is
O(log(N + r)), i.e. it does not grow with r while r ≪ N, and r beyond the image diagonal
short-cuts to global statistics.  The disc is the set of
integer offsets with dx² + dy² ≤ r²; statistics use only pixels inside the image (and inside
the optional mask): μ = (H·M ∗ f)/(M ∗ f), which equals ``cv2.filter2D`` with the normalised
disc kernel on the interior and stays unbiased at the border.
"""
from __future__ import annotations

import functools

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
        var -= mu * mu
        np.maximum(var, 0.0, out=var)
        sd = np.sqrt(var, out=var)
        mu += c[:, None, None].astype(np.float32)
        wsum = cnt
    else:
        wsum = sums[-1]
        ok = wsum > 1e-6 * max(float(wsum.max()), 1e-300)
        inv = 1.0 / np.where(ok, wsum, 1.0)
        mu_d = sums[:n] * inv
        var = sums[n:2 * n] * inv
        var -= mu_d * mu_d
        np.maximum(var, 0.0, out=var)
        sd = np.sqrt(var)
        mu = mu_d + c[:, None, None]
        wsum = np.where(ok, wsum, 0.0)
    return (mu[0], sd[0], wsum) if single else (mu, sd, wsum)


def match(hn, mu_n, sd_n, mu, sd, eps):
    """Eq. (3): H = μ + σ/σ_n (H_n − μ_n), with σ_n floored at ``eps``."""
    return mu + sd / np.maximum(sd_n, eps) * (hn - mu_n)


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


def _map(img: Image, port: str, what: str = "concentration") -> np.ndarray:
    if img.channels != 1:
        raise BadInput(port, f"{port} must be a one-channel {what} map, got {img.channels} channels")
    a = img.pixels[:, :, 0]
    if not np.isfinite(a).all():
        raise BadInput(port, f"{port} holds NaN or Inf values")
    if (a < 0).any():
        raise BadInput(port, f"{port} holds negative concentrations (min {a.min():.4g}); "
                             "volume fractions must be ≥ 0")
    return a


def _mask(mask: Mask | None, shape, port="mask") -> np.ndarray | None:
    if mask is None:
        return None
    if mask.alpha.shape != tuple(shape):
        raise BadInput(port, f"mask is {mask.alpha.shape[1]}×{mask.alpha.shape[0]}, "
                             f"the maps are {shape[1]}×{shape[0]}")
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
    dimensionless hemoglobin (or melanin) volume fractions; ``radius`` is in pixels.  Cost per
    pixel does not grow with r (FFT convolution; r beyond the image diagonal = global match).
    """

    version = "4"
    inputs = {"neutral": In(Image, "neutral map H_n (one channel, volume fraction)"),
              "target": In(Image, "target map H of the same size"),
              "mask": In(Mask, "where statistics are taken (skin)", optional=True)}
    outputs = {"matched": Out(Image, "H_n matched to the target's local statistics (eq. 3)"),
               "scale": Out(Image, "σ/σ_n (eq. 5), at stats_size"),
               "bias": Out(Image, "μ (eq. 5), at stats_size"),
               "neutral_mean": Out(Image, "μ_n (eq. 4), at stats_size")}
    tolerance = {"rtol": 1e-4, "atol": 1e-5}

    class Params(Node.Params):
        radius: float = Field(16.0, description="disc radius r in pixels (> 0)")
        stats_size: int = Field(256, ge=0, description="longer side of the scale/bias maps (0 = full size)")
        eps: float = Field(1e-6, gt=0, description="floor of σ_n (volume fraction); below it scale = 1")

    def compute(self, neutral: Image, target: Image, mask: Mask | None = None):
        p = self.params
        if not p.radius > 0:
            raise BadInput("radius", f"radius must be > 0 pixels, got {p.radius}")
        if neutral.pixels.shape[:2] != target.pixels.shape[:2]:
            raise BadInput("target", f"map sizes differ: neutral is {neutral.width}×{neutral.height}, "
                                     f"target is {target.width}×{target.height}")
        hn = _map(neutral, "neutral")
        ht = _map(target, "target")
        m = _mask(mask, hn.shape)
        (mu_n, mu), (sd_n, sd), w = local_mean_std(np.stack([hn, ht]), p.radius, m)
        self.ctx.progress(0.8, "statistics done")
        # σ_n below the floor (a flat neighbourhood, or a one-pixel disc): H_n − μ_n is 0 there
        # anyway, so the scale is set to 1 rather than to a ratio of round-off values
        floor = max(p.eps, 1e-3 * float(hn.std()) if m is None else p.eps)
        flat = sd_n <= floor
        scale = np.where(flat, 1.0, sd / np.maximum(sd_n, floor)).astype(sd.dtype, copy=False)
        out = mu + scale * (hn - mu_n)  # eq. (3)
        if m is not None:  # no statistics (no skin under the disc) or outside the skin: unchanged
            ok = w > 0
            out = np.where(ok & (m > 0), out, hn)
            scale = np.where(ok, scale, 1.0)
            mu = np.where(ok, mu, hn)
            mu_n = np.where(ok, mu_n, hn)
        # means of non-negative maps are ≥ 0; clip the FFT round-off (~1e-7)
        bias = np.maximum(mu, 0.0)
        mu_n = np.maximum(mu_n, 0.0)
        shp = stats_shape(hn.shape, p.stats_size)
        return {"matched": Image(np.maximum(out, 0.0).astype(np.float32)),
                "scale": Image(resize_to(scale, shp).astype(np.float32)),
                "bias": Image(resize_to(bias, shp).astype(np.float32)),
                "neutral_mean": Image(resize_to(mu_n, shp).astype(np.float32))}

    @classmethod
    def examples(cls):
        rng = np.random.default_rng(5)
        a = Image(rng.random((40, 56, 1), dtype=np.float32) * 0.1)
        b = Image(rng.random((40, 56, 1), dtype=np.float32) * 0.2 + 0.05)
        return [({"radius": 5.0, "stats_size": 0}, {"neutral": a, "target": b}),
                ({"radius": 3.5, "stats_size": 20}, {"neutral": a, "target": b})]


class AppearanceRig(Node):
    """Appearance rig (Jimenez 2010 §4.2, eqs. 4–6): H = Σ w_i bias_i + H_0 Σ w_i scale_i.

    ``neutral`` is H_n and ``neutral_mean`` μ_n (H_0 = H_n − μ_n, bias_0 = μ_n, scale_0 = 1);
    ``scales``/``biases`` are the basis entries i = 1…k from LocalHistMatch (any resolution:
    they are low-frequency and resized bilinearly, §6).  ``weights`` = [w_0, w_1, …, w_k] must
    sum to one.  ``hemoglobin_scale`` multiplies the result globally (the paper uses 1.27 for
    anger, 0.81 for fear).  Output: hemoglobin volume fraction map (clipped at 0).
    """

    version = "1"
    inputs = {"neutral": In(Image, "neutral map H_n (one channel)"),
              "neutral_mean": In(Image, "μ_n, local mean of H_n (any resolution)"),
              "scales": In(Image, "scale_i = σ_i/σ_n, i = 1…k", variadic=True),
              "biases": In(Image, "bias_i = μ_i, i = 1…k", variadic=True)}
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
        hn = _map(neutral, "neutral")
        shp = hn.shape
        mu_n = resize_to(_map(neutral_mean, "neutral_mean"), shp)
        w0 = p.weights[0]
        bias = w0 * mu_n
        scale = np.full(shp, w0)
        for i, (s, b) in enumerate(zip(scales, biases), start=1):
            if s.channels != 1 or b.channels != 1:
                raise BadInput("scales", f"basis entry {i}: scale and bias must be one-channel maps")
            sa = s.pixels[:, :, 0].astype(np.float64)
            if (sa < 0).any():
                raise BadInput("scales", f"basis entry {i}: negative scale (σ ratios are ≥ 0)")
            bias += p.weights[i] * resize_to(_map(b, "biases"), shp)
            scale += p.weights[i] * resize_to(sa, shp)
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
    inputs = {"hemoglobin": In(Image, "neutral hemoglobin map H_n"),
              "regions": In(Mask, "where the flush goes (e.g. cheeks)"),
              "extra": In(Mask, "a second region with half the gain (e.g. lips, nose)", optional=True)}
    outputs = {"hemoglobin": Out(Image, "example flushed map")}

    class Params(Node.Params):
        gain: float = Field(0.8, ge=0, description="relative hemoglobin increase at the centre of the region")
        soften: float = Field(12.0, ge=0, description="Gaussian σ of the region edges (pixels)")

    def compute(self, hemoglobin: Image, regions: Mask, extra: Mask | None = None):
        from scipy.ndimage import gaussian_filter

        hn = _map(hemoglobin, "hemoglobin")
        g = _mask(regions, hn.shape, "regions")
        if extra is not None:
            g = g + 0.5 * _mask(extra, hn.shape, "extra")
        g = gaussian_filter(g, self.params.soften) if self.params.soften > 0 else g
        g = g / max(g.max(), 1e-12)
        return Image((hn * (1.0 + self.params.gain * g)).astype(np.float32))
