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
