"""LocalHistMatch (Jimenez 2010 §4.1) against outside references: cv2.filter2D with a
normalised disc kernel, skimage.exposure.match_histograms, brute-force local histogram matching."""
import numpy as np
import pytest

from graphkit import Image, Mask
from nodes.jimenez.histmatch import LocalHistMatch, disc_kernel, local_mean_std

cv2 = pytest.importorskip("cv2", reason="OpenCV is the reference for the disc filter")


def _filter_stats(h, r, m=None, border=None):
    k = disc_kernel(r)
    k /= k.sum()  # normalised disc kernel f of eq. (1)
    if border is not None:  # plain filter2D (interior comparison)
        mu = cv2.filter2D(h, cv2.CV_64F, k, borderType=border)
        ex2 = cv2.filter2D(h * h, cv2.CV_64F, k, borderType=border)
        return mu, np.sqrt(np.maximum(ex2 - mu * mu, 0))
    m = np.ones_like(h) if m is None else m
    c = cv2.BORDER_CONSTANT
    den = cv2.filter2D(m, cv2.CV_64F, k, borderType=c)
    with np.errstate(divide="ignore", invalid="ignore"):  # no mask under the disc: NaN, not compared
        mu = cv2.filter2D(h * m, cv2.CV_64F, k, borderType=c) / den
        ex2 = cv2.filter2D(h * h * m, cv2.CV_64F, k, borderType=c) / den
    with np.errstate(invalid="ignore"):
        return mu, np.sqrt(np.maximum(ex2 - mu * mu, 0))


@pytest.mark.parametrize("r", [1.0, 2.5, 7.0, 16.0, 31.0])
def test_disc_mean_std_equal_filter2D(r):
    rng = np.random.default_rng(int(r * 10))
    h = rng.random((150, 173))
    mu, sd, _ = local_mean_std(h, r)
    R = int(r)
    rmu, rsd = _filter_stats(h, r, border=cv2.BORDER_REFLECT_101)
    inner = np.s_[R:-R, R:-R]
    np.testing.assert_allclose(mu[inner], rmu[inner], atol=1e-6, rtol=0)
    np.testing.assert_allclose(sd[inner], rsd[inner], atol=1e-6, rtol=0)
    # everywhere, with statistics over the in-image part of the disc
    rmu, rsd = _filter_stats(h, r)
    np.testing.assert_allclose(mu, rmu, atol=1e-6, rtol=0)
    np.testing.assert_allclose(sd, rsd, atol=1e-6, rtol=0)


def test_disc_stats_with_mask_equal_filter2D():
    rng = np.random.default_rng(11)
    h = rng.random((120, 140)) * 0.3
    m = np.zeros_like(h)
    m[20:100, 15:120] = 1.0
    m[50:60, 40:90] = 0.0
    mu, sd, w = local_mean_std(h, 9.0, m)
    rmu, rsd = _filter_stats(h, 9.0, m)
    ok = w > 0
    np.testing.assert_allclose(mu[ok], rmu[ok], atol=1e-6, rtol=0)
    np.testing.assert_allclose(sd[ok], rsd[ok], atol=1e-6, rtol=0)


def test_large_map_r128_equal_filter2D_on_a_window():
    rng = np.random.default_rng(12)
    h = rng.random((600, 520))
    mu, sd, _ = local_mean_std(h, 128.0)
    rmu, rsd = _filter_stats(h, 128.0, border=cv2.BORDER_REFLECT_101)
    inner = np.s_[128:-128, 128:-128]
    np.testing.assert_allclose(mu[inner], rmu[inner], atol=1e-6, rtol=0)
    np.testing.assert_allclose(sd[inner], rsd[inner], atol=1e-6, rtol=0)


def test_global_limit_matches_target_stats_and_skimage():
    from skimage.exposure import match_histograms

    rng = np.random.default_rng(13)
    hn = np.clip(rng.normal(0.10, 0.02, (256, 256)), 0, None)
    ht = np.clip(rng.normal(0.16, 0.035, (256, 256)), 0, None)
    node = LocalHistMatch(LocalHistMatch.Params(radius=400.0, stats_size=0))  # r > diagonal (362)
    out = node.compute(neutral=Image(hn[..., None]), target=Image(ht[..., None]))["matched"].pixels[..., 0]
    assert abs(out.mean() - ht.mean()) < 1e-6
    assert abs(out.std() - ht.std()) < 1e-6
    ref = match_histograms(hn, ht)
    sigma = ht.std()
    err = np.abs(out - ref)
    print(f"global limit vs match_histograms: mean |err| = {err.mean() / sigma:.4%} of σ, "
          f"rms {np.sqrt((err ** 2).mean()) / sigma:.4%}, p99 {np.percentile(err, 99) / sigma:.3%}")
    assert err.mean() <= 0.01 * sigma
    assert np.percentile(err, 99) <= 0.05 * sigma
    # the FFT path just below the global limit agrees with the shortcut
    mu, sd, _ = local_mean_std(hn, 361.0)
    np.testing.assert_allclose(mu, hn.mean(), atol=1e-6)
    np.testing.assert_allclose(sd, hn.std(), atol=1e-6)


def _brute_force_lhm(hn, ht, r, mask, pts):
    """Exact local histogram matching at pixels ``pts``: percentile of H_n(x) among the
    neutral values in the disc (inside the mask) → that quantile of the target's values."""
    H, W = hn.shape
    R = int(r)
    dy, dx = np.nonzero(disc_kernel(r))
    dy, dx = dy - R, dx - R
    out = []
    for y, x in pts:
        yy, xx = y + dy, x + dx
        ok = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
        yy, xx = yy[ok], xx[ok]
        ok = mask[yy, xx] > 0.5
        a, b = hn[yy[ok], xx[ok]], ht[yy[ok], xx[ok]]
        q = (np.sum(a < hn[y, x]) + 0.5 * np.sum(a == hn[y, x])) / len(a)
        out.append(np.quantile(b, np.clip(q, 0, 1)))
    return np.array(out)


def test_error_against_brute_force_local_histogram_matching_on_real_maps():
    """Real maps: the astronaut's hemoglobin (neutral) matched to its melanin map rescaled and
    mirrored (a real map with different local structure).  Error is reported; the Gaussian
    approximation must beat doing nothing by a wide margin."""
    from skimage import data, transform

    from nodes.common.color import srgb_to_linear
    from nodes.jimenez.chromophores import SkinChromophores

    photo = srgb_to_linear(data.astronaut()[30:230, 120:320] / 255.0)
    photo = transform.resize(photo, (128, 128), anti_aliasing=True).astype(np.float32)
    out = SkinChromophores().compute(image=Image(photo))
    skin = out["skin"].alpha
    hn = out["hemoglobin"].pixels[..., 0].astype(np.float64)
    ht = out["hemoglobin"].pixels[:, ::-1, 0].astype(np.float64) * 1.5 + 0.01 * skin  # mirrored face, flushed
    mask = skin * skin[:, ::-1]
    r = 10.0
    rng = np.random.default_rng(0)
    ys, xs = np.nonzero(mask > 0.5)
    pick = rng.choice(len(ys), size=min(600, len(ys)), replace=False)
    pts = list(zip(ys[pick], xs[pick]))
    exact = _brute_force_lhm(hn, ht, r, mask, pts)
    sigma = ht[mask > 0.5].std()
    base = np.abs(np.array([hn[y, x] for y, x in pts]) - exact)
    for mode in ("exact", "fast"):
        node = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=0, mode=mode))
        matched = node.compute(neutral=Image(hn[..., None].astype(np.float32)),
                               target=Image(ht[..., None].astype(np.float32)),
                               mask=Mask(mask))["matched"].pixels[..., 0]
        approx = np.array([matched[y, x] for y, x in pts])
        err = np.abs(approx - exact)
        print(f"approximate ({mode} statistics) vs exact local HM (r={r}, {len(pts)} px): "
              f"mean |err| = {err.mean() / sigma:.3f} σ, median {np.median(err) / sigma:.3f} σ, "
              f"p90 {np.percentile(err, 90) / sigma:.3f} σ (unmatched H_n: {base.mean() / sigma:.3f} σ)")
        assert err.mean() < 0.5 * base.mean()


# --------------------------------------------------------------------------------------------
# the fast path (statistics on a grid of ⌊r/4⌋-pixel cells) against the exact one, which the
# tests above hold to cv2.filter2D


def _astronaut_maps(n):
    """Real maps: the astronaut's hemoglobin (neutral) and a mirrored, flushed copy (target),
    with the skin mask of both (as in the brute-force test above)."""
    from skimage import data, transform

    from nodes.common.color import srgb_to_linear
    from nodes.jimenez.chromophores import SkinChromophores

    photo = srgb_to_linear(data.astronaut()[:400, 50:450] / 255.0)
    photo = transform.resize(photo, (n, n), anti_aliasing=True).astype(np.float32)
    out = SkinChromophores().compute(image=Image(photo))
    skin = out["skin"].alpha
    hn = out["hemoglobin"].pixels[..., 0]
    return hn, hn[:, ::-1] * 1.5 + 0.01 * skin, skin * skin[:, ::-1]


def _fast_vs_exact(hn, ht, m, r):
    """|fast − exact| of the matched map over the mask (or everywhere), in units of the
    target's σ there: (mean, p99, max)."""
    kw = {"neutral": Image(hn[..., None]), "target": Image(ht[..., None]), "mask": None if m is None else Mask(m)}
    exact = LocalHistMatch(LocalHistMatch.Params(radius=r, mode="exact")).compute(**kw)["matched"].pixels[..., 0]
    fast = LocalHistMatch(LocalHistMatch.Params(radius=r)).compute(**kw)["matched"].pixels[..., 0]
    sel = np.ones(exact.shape, bool) if m is None else m > 0.5
    d = np.abs(fast - exact)[sel] / ht[sel].std()
    return d.mean(), np.percentile(d, 99), d.max()


@pytest.mark.parametrize("r", [16.0, 32.0])
def test_fast_path_close_to_exact_on_gaussian_data(r):
    rng = np.random.default_rng(21)
    hn = np.clip(rng.normal(0.10, 0.02, (256, 256)), 0, None).astype(np.float32)
    ht = np.clip(rng.normal(0.16, 0.035, (256, 256)), 0, None).astype(np.float32)
    mean, p99, mx = _fast_vs_exact(hn, ht, None, r)
    print(f"fast vs exact, Gaussian data, r={r}: mean |Δ| = {mean:.4f} σ, p99 {p99:.4f} σ, max {mx:.3f} σ")
    # white noise is the hardest case (all its structure is finer than a cell); the error
    # falls as 1/r with the noise of the local mean itself (σ/√(πr²) = 0.035 σ at r = 16)
    assert mean <= 0.02 * 16 / r
    assert p99 <= 0.07 * 16 / r


def test_fast_path_close_to_exact_on_real_maps():
    hn, ht, m = _astronaut_maps(256)
    for mask in (m, None):
        for r in (8.0, 16.0, 32.0):
            mean, p99, mx = _fast_vs_exact(hn, ht, mask, r)
            print(f"fast vs exact, astronaut hemoglobin, {'skin mask' if mask is not None else 'no mask'}, "
                  f"r={r}: mean |Δ| = {mean:.4f} σ, p99 {p99:.4f} σ, max {mx:.2f} σ")
            # where σ_n → 0 (the edge of the skin, pixels of almost no hemoglobin) eq. (3)
            # scales by σ/σ_n ≫ 1 in both paths: rare large differences (max), small mean
            assert mean <= 0.03
            assert p99 <= 0.2


@pytest.mark.parametrize("shape", [(250, 333), (97, 140)])
def test_fast_path_on_sizes_that_are_not_whole_cells(shape):
    rng = np.random.default_rng(22)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    base = 0.1 + 0.03 * np.sin(xx / 17.0) * np.cos(yy / 23.0)  # low-frequency structure + noise
    hn = (base + rng.normal(0, 0.01, shape)).clip(0).astype(np.float32)
    ht = (1.4 * base + rng.normal(0, 0.015, shape)).clip(0).astype(np.float32)
    for r in (12.0, 20.0):  # cells of 3 and 5 px: partial last row and column
        mean, p99, mx = _fast_vs_exact(hn, ht, None, r)
        print(f"fast vs exact, {shape}, r={r}: mean |Δ| = {mean:.4f} σ, p99 {p99:.4f} σ")
        # (statistics shifted by one cell would give 0.018 σ and 0.011 σ mean: alignment matters)
        assert mean <= 0.015 * 12 / r and p99 <= 0.055 * 12 / r


def test_fast_path_is_exact_below_8_px_and_in_the_global_limit():
    rng = np.random.default_rng(23)
    hn = rng.random((60, 70)).astype(np.float32)
    ht = (rng.random((60, 70)) * 2).astype(np.float32)
    for r in (3.0, 7.9, 200.0):
        kw = {"neutral": Image(hn), "target": Image(ht)}
        a = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=0)).compute(**kw)
        b = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=0, mode="exact")).compute(**kw)
        for port in a:
            np.testing.assert_array_equal(a[port].pixels, b[port].pixels)


def test_fast_path_cost_per_pixel_does_not_grow_with_r():
    """The docstring's claim, structurally: the cell is c = ⌊r/4⌋ px and the disc kernel on the
    grid at most 13 × 13 taps for every r ≥ 8 (r/c < 4 + 4/c cells), so the grid work is
    ≤ 169/c² taps per pixel (falling with r); the per-pixel passes (cell sums, eq. 3) do not
    depend on r at all."""
    from nodes.jimenez.histmatch import CELLS_PER_RADIUS, grid_disc_kernel, stats_cell

    for r in (8.0, 9.5, 11.99, 15.9, 16.0, 31.0, 64.0, 128.0, 300.0, 1000.0):
        c = stats_cell(4096, 4096, r)
        k = grid_disc_kernel(r, c)
        assert c >= 2 and c > r / CELLS_PER_RADIUS - 1
        assert k.shape[0] <= 13
        assert k.size / c ** 2 <= 169 / 4
        # and the kernel is the disc: its mass is the disc area, in cells
        assert abs(k.sum() * c * c - np.pi * r * r) <= 0.01 * np.pi * r * r


def test_banded_eq3_equals_resizing_whole():
    """apply_scale_bias works on bands of rows; the result equals resizing a, b whole (cv2
    bilinear) and evaluating eq. (3) with numpy."""
    from nodes.jimenez.histmatch import apply_scale_bias, grid_resize

    rng = np.random.default_rng(24)
    for (H, W), c in (((1024, 768), 4), ((1024, 512), 32), ((300, 410), 8), ((333, 250), 5)):
        g = (-(-H // c), -(-W // c))
        hn = (rng.random((H, W)) * 0.1).astype(np.float32)
        s = (rng.random(g) + 0.5).astype(np.float32)
        mu = (rng.random(g) * 0.1).astype(np.float32)
        mu_n = (rng.random(g) * 0.1).astype(np.float32)
        out = apply_scale_bias(hn, s, mu, mu_n, c)
        a = grid_resize(s, c, (H, W))
        b = grid_resize(mu - s * mu_n, c, (H, W))
        np.testing.assert_allclose(out, np.maximum(a * hn + b, 0), atol=1e-7, rtol=0)


# --------------------------------------------------------------------------------------------
# the fast path's grid, structurally: where its values sit (issue 10: shifting the grid by half
# a cell passed the fast-vs-exact bounds above, which allow for the approximation itself)


def _disc_mean_std_by_sampling(h, cy, cx, r, n=400):
    """Mean and σ of a piecewise-constant pixel map over the disc of radius r px centred at
    (cy, cx) (continuous coordinates, pixel p covering [p, p + 1)), by point sampling the disc
    on an n × n lattice: an independent reference (no code of nodes.jimenez)."""
    t = (np.arange(n) + 0.5) / n * 2 - 1
    yy, xx = np.meshgrid(t * r, t * r, indexing="ij")
    inside = yy ** 2 + xx ** 2 <= r * r
    v = h[np.floor(cy + yy[inside]).astype(int), np.floor(cx + xx[inside]).astype(int)]
    return v.mean(), v.std()


@pytest.mark.parametrize("r,c", [(16.0, 4), (20.0, 5), (30.0, 7)])
def test_grid_statistics_are_the_disc_statistics_at_the_cell_centres(r, c):
    """On a map constant within c × c cells the fast path's grid statistics are exact (its
    docstring) and sit at the cell centres ((i + ½)·c px).  Checked at interior cells against
    point sampling of the disc; a grid or kernel shifted by half a cell is off by ~5 % of σ."""
    from nodes.jimenez.histmatch import grid_mean_std, stats_cell

    rng = np.random.default_rng(int(r))
    g = 24
    cells = rng.random((g, g))
    h = np.kron(cells, np.ones((c, c))).astype(np.float32)  # H = W = g·c
    assert stats_cell(*h.shape, r) == c
    mu, sd, _ = grid_mean_std([h], r)
    assert mu.shape == (1, g, g)
    R = int(np.ceil(r / c)) + 1
    errs_mu, errs_sd = [], []
    for i in range(R, g - R, 3):
        for j in range(R + 1, g - R, 4):
            m_ref, s_ref = _disc_mean_std_by_sampling(h, (i + 0.5) * c, (j + 0.5) * c, r)
            errs_mu.append(abs(mu[0, i, j] - m_ref))
            errs_sd.append(abs(sd[0, i, j] - s_ref))
    sigma = h.std()
    print(f"grid stats vs sampled disc, r={r}, c={c}: max |Δμ| = {max(errs_mu) / sigma:.4f} σ, "
          f"max |Δσ| = {max(errs_sd) / sigma:.4f} σ")
    assert max(errs_mu) <= 0.006 * sigma and max(errs_sd) <= 0.006 * sigma


@pytest.mark.parametrize("shape,c", [((96, 120), 4), ((95, 121), 5), ((65, 35), 5), ((64, 64), 8), ((97, 141), 2)])
def test_grid_resize_puts_cell_values_at_cell_centres(shape, c):
    """grid_resize is bilinear with the value of cell i at (i + ½)·c px, held flat beyond the
    outer centres: the same as numpy's np.interp along each axis (separable).  Where the last
    cells stick out of the image the grid is first re-sampled (np.interp at the centres of g
    cells tiling the image), then spread the same way."""
    from nodes.jimenez.histmatch import grid_resize

    H, W = shape
    gH, gW = -(-H // c), -(-W // c)
    rng = np.random.default_rng(H + W + c)
    a = rng.random((gH, gW)).astype(np.float64)
    out = grid_resize(a.astype(np.float32), c, shape)

    def axis(vals, n):  # one axis of the reference: vals (g,) on cells of c px -> (n,) pixels
        g = len(vals)
        if g * c != n:  # cells of n/g px tiling the image, values interpolated at their centres
            vals = np.interp((np.arange(g) + 0.5) * (n / g) / c - 0.5, np.arange(g), vals)
        return np.interp((np.arange(n) + 0.5) / (n / g) - 0.5, np.arange(g), vals)

    rows = np.stack([axis(a[i], W) for i in range(gH)])
    ref = np.stack([axis(rows[:, x], H) for x in range(W)], axis=1)
    np.testing.assert_allclose(out, ref, atol=2e-6, rtol=0)
    if H % c == 0 and W % c == 0 and c % 2 == 1:  # cell centres are pixel centres: the cell's value
        np.testing.assert_allclose(out[c // 2::c, c // 2::c], a, atol=2e-6)
    # onto another resolution covering the same image (the eq. 5 maps at stats_size)
    small = grid_resize(a.astype(np.float32), c, shape, (H // 3, W // 2))
    assert small.shape == (H // 3, W // 2)


def test_stats_cell_follows_its_rule():
    """c = ⌊r/4⌋ (1 below 8 px); 1 (the global limit) exactly when the disc covers the image
    from every pixel, r² ≥ (H − 1)² + (W − 1)²: a 24-32-40 triangle puts r on the boundary."""
    from nodes.jimenez.histmatch import stats_cell

    assert stats_cell(25, 33, 40.0) == 1  # r² = 24² + 32²
    assert stats_cell(25, 33, 39.99) == 9
    assert stats_cell(33, 25, 39.99) == 9
    assert stats_cell(1000, 1000, 7.99) == 1 and stats_cell(1000, 1000, 8.0) == 2
    assert stats_cell(1000, 1000, 31.9) == 7
