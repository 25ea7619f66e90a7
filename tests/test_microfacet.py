"""nodes.common.microfacet against closed forms, GPU Gems 3 ch. 14 and Mitsuba 3."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.common.microfacet import beckmann_D, kelemen_brdf, kelemen_specular, schlick_fresnel


def _unit(x):
    x = np.asarray(x, float)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_beckmann_closed_form_and_normalisation():
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, np.pi / 2 - 1e-3, 500)
    for m in (0.05, 0.2, 0.35, 0.7, 1.2):
        want = [math.exp(-math.tan(t) ** 2 / m**2) / (math.pi * m**2 * math.cos(t) ** 4) for t in theta]
        np.testing.assert_allclose(beckmann_D(np.cos(theta), m), want, rtol=1e-12, atol=1e-300)
        # ∫ D cosθ dω = 2π ∫ D(θ) cosθ sinθ dθ = 1 (Gauss–Legendre in u = cos²θ... use θ grid)
        from scipy.integrate import quad

        val, _ = quad(lambda t: 2 * np.pi * beckmann_D(np.cos(t), m) * np.cos(t) * np.sin(t),
                      0, np.pi / 2, limit=200, points=[min(3 * m, 1.5)])
        assert abs(val - 1) < 1e-7, (m, val)
    assert beckmann_D(-0.3, 0.3) == 0.0 and beckmann_D(0.0, 0.3) == 0.0


def test_beckmann_vs_mitsuba():
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the outside reference for the Beckmann NDF")
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(1)
    dirs = _unit(rng.normal(size=(300, 3)))
    dirs[:, 2] = np.abs(dirs[:, 2])
    worst = 0.0
    for m in (0.1, 0.3, 0.5, 0.9):
        d = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, m)  # alpha = m (see module doc)
        ours = beckmann_D(dirs[:, 2], m)
        theirs = np.array([d.eval(mi.Vector3f(*map(float, w))) for w in dirs])
        keep = theirs > 1e-30
        rel = np.abs(ours[keep] - theirs[keep]) / theirs[keep]
        worst = max(worst, rel.max())
    assert worst < 2e-5, worst  # Mitsuba evaluates in float32 (measured: 1.3e-5)
    # the convention is pinned: alpha = sqrt(2)·m (alpha read as the per-axis RMS slope) disagrees
    d = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, 0.3 * math.sqrt(2))
    assert abs(d.eval(mi.Vector3f(0, 0, 1)) / beckmann_D(1.0, 0.3) - 0.5) < 1e-6


def test_schlick():
    assert schlick_fresnel(1.0, 0.028) == pytest.approx(0.028, abs=1e-15)
    assert schlick_fresnel(0.0, 0.028) == pytest.approx(1.0, abs=1e-15)
    c = np.linspace(0, 1, 11)
    np.testing.assert_allclose(schlick_fresnel(c, 0.04), 0.04 + 0.96 * (1 - c) ** 5, rtol=1e-14)


def _gpugems_ks_skin_specular(N, L, V, m, rho_s, F0=0.028):
    """Literal transcription of GPU Gems 3 ch. 14 listings 14-1/14-2 (texture = exact PH)."""
    ndotl = float(np.dot(N, L))
    if ndotl <= 0:
        return 0.0
    h = L + V
    H = h / np.linalg.norm(h)
    ndoth = float(np.dot(N, H))
    alpha = math.acos(min(ndoth, 1.0))
    ta = math.tan(alpha)
    PH = 1.0 / (m * m * ndoth**4) * math.exp(-(ta * ta) / (m * m))
    base = 1.0 - float(np.dot(V, H))
    F = base**5 + F0 * (1 - base**5)
    frSpec = max(PH * F / float(np.dot(h, h)), 0.0)
    return ndotl * rho_s * frSpec


def test_kelemen_vs_gpugems_listing():
    rng = np.random.default_rng(2)
    n = _unit(rng.normal(size=(200, 3)) * [0.2, 0.2, 1] + [0, 0, 1])
    l = _unit(rng.normal(size=(200, 3)) + [0, 0, 0.5])
    v = _unit(rng.normal(size=(200, 3)) + [0, 0, 1.0])
    ours = kelemen_specular(n, l, v, 0.3, 0.18)
    want = [_gpugems_ks_skin_specular(a, b, c, 0.3, 0.18) for a, b, c in zip(n, l, v)]
    np.testing.assert_allclose(ours, want, rtol=1e-10, atol=1e-14)
    assert (ours >= 0).all() and (ours[np.sum(n * l, -1) <= 0] == 0).all()


def test_kelemen_brdf_is_huang_eq5_and_broadcasts():
    n = np.array([0, 0, 1.0])
    l = _unit([0.3, 0.1, 1.0])
    v = _unit([-0.2, 0.0, 1.0])
    H = _unit(l + v)
    want = beckmann_D(H[2], 0.25) * schlick_fresnel(H @ l, 0.05) / (2 * (1 + l @ v))
    assert kelemen_brdf(n, l, v, 0.25, 0.05) == pytest.approx(want, rel=1e-13)
    out = kelemen_specular(np.broadcast_to(n, (4, 5, 3)), l, v, np.full((4, 5), 0.3), 0.2)
    assert out.shape == (4, 5)
    # L = −V (h = 0) and back-lit give 0, not NaN
    assert kelemen_specular(n, _unit([0.1, 0, 1]), _unit([-0.1, 0, -1]), 0.3, 1.0) == 0.0


def test_float32_is_the_same_maths():
    """dtype=float32 (SkinShade's per-pixel path) runs the same functions in float32: equal to
    the float64 reference within float32 rounding, float32 out, no NaN at grazing/back-facing
    normals (where cos⁴θ_h would underflow) and 0 where N·L ≤ 0."""
    rng = np.random.default_rng(4)
    n = _unit(rng.normal(size=(64, 48, 3)) * [0.4, 0.4, 1] + [0, 0, -1])
    n[0, :4] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], _unit([1, 0, -1e-12])]
    l, v = _unit([0.4, -0.3, -1.0]), np.array([0, 0, -1.0])
    for m in (0.1, 0.35, 0.9):
        want = kelemen_specular(n, l, v, m, 0.18, 0.028)
        got = kelemen_specular(n.astype(np.float32), l.astype(np.float32), v.astype(np.float32),
                               m, 0.18, 0.028, dtype=np.float32)
        assert got.dtype == np.float32 and np.isfinite(got).all()
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-7 * want.max())
        assert (got[np.sum(n * l, -1) <= 0] == 0).all()
    c = np.linspace(-1, 1, 2001)
    c[1000] = 1e-30  # cos²θ_h below √tiny: 0, not 0/0
    d32 = beckmann_D(c.astype(np.float32), 0.3, dtype=np.float32)
    assert d32.dtype == np.float32 and np.isfinite(d32).all()
    np.testing.assert_allclose(d32, beckmann_D(c, 0.3), rtol=2e-5, atol=1e-6)
    assert schlick_fresnel(np.float32(0.5), 0.028, dtype=np.float32).dtype == np.float32
