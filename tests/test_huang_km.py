"""Kubelka–Munk maths of nodes/huang/km.py (Huang 2013 §3.1, §4): exact identities and limits."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nodes.huang import km

pos = st.floats(0.0, 200.0, allow_nan=False)
thick = st.floats(0.0, 5.0, allow_nan=False)


def _textbook_R0_T(S, K, X):
    """Eqs. 1–2 as printed (sinh/cosh, a = 1 + K/S, b = √(a² − 1)), for moderate values only."""
    a = 1 + K / S
    b = np.sqrt(a * a - 1)
    d = a * np.sinh(b * S * X) + b * np.cosh(b * S * X)
    return np.sinh(b * S * X) / d, b / d


def test_matches_textbook_form():
    rng = np.random.default_rng(0)
    S, K, X = rng.uniform(0.1, 50, 2000), rng.uniform(0.01, 20, 2000), rng.uniform(0.001, 1, 2000)
    R0, T = km.layer_R0_T(S, K, X)
    R0b, Tb = _textbook_R0_T(S, K, X)
    np.testing.assert_allclose(R0, R0b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(T, Tb, rtol=1e-11, atol=1e-15)


@settings(max_examples=300, deadline=None)
@given(S=pos, K=pos, d1=thick, d2=thick)
def test_layer_over_same_layer_is_one_thicker_layer(S, K, d1, d2):
    # d1 over d2 of the same material = one layer of d1 + d2 (Rt, Rb and T), to 1e-12
    R1, T1 = km.layer_R0_T(S, K, d1)
    R2, T2 = km.layer_R0_T(S, K, d2)
    R, T = km.layer_R0_T(S, K, d1 + d2)
    Rt, Rb, Tc = km.compose((R1, R1, T1), (R2, R2, T2))
    assert abs(Rt - R) <= 1e-12 and abs(Rb - R) <= 1e-12 and abs(Tc - T) <= 1e-12


@settings(max_examples=200, deadline=None)
@given(S=st.floats(1e-3, 200.0), K=pos)
def test_infinite_thickness_gives_r_infinity(S, K):
    rinf = km.r_infinity(S, K)
    from decimal import Decimal, getcontext

    getcontext().prec = 60  # the textbook form a − √(a² − 1) in 60-digit decimals (no cancellation)
    a = 1 + Decimal(K) / Decimal(S)
    assert rinf == pytest.approx(float(a - (a * a - 1).sqrt()), rel=1e-14)
    R, T = km.layer_R0_T(S, K, np.inf)
    assert R == pytest.approx(rinf, abs=1e-15) and T == 0.0
    R, T = km.layer_R0_T(S, K, 1e300)  # no overflow for huge X
    assert np.isfinite(R) and np.isfinite(T)
    beta = np.sqrt(K * (K + 2 * S))
    if beta > 1e-100:
        R, T = km.layer_R0_T(S, K, 40.0 / beta)  # βX = 40: opaque to double precision
        assert R == pytest.approx(rinf, rel=1e-12) and T < 1e-16
    # over any background, a thick layer hides it
    Rbig = km.reflectance_over(S, K, np.inf, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(Rbig, rinf, atol=1e-15)


def test_limits():
    S = np.array([0.0, 3.0, 0.0, 7.0])
    K = np.array([2.0, 0.0, 0.0, 1.0])
    # X = 0: nothing
    R, T = km.layer_R0_T(S, K, 0.0)
    assert (R == 0).all() and (T == 1).all()
    # X → 0: R0 ≈ S X, 1 − T ≈ (S + K) X
    X = 1e-9
    R, T = km.layer_R0_T(S, K, X)
    np.testing.assert_allclose(R, S * X, rtol=1e-8, atol=1e-300)
    np.testing.assert_allclose(1 - T, (S + K) * X, rtol=1e-6, atol=1e-16)
    # K = 0: R0 = SX/(1+SX), T = 1/(1+SX), R + T = 1 (no absorption)
    for X in (1e-12, 0.01, 1.0, 1e3, 1e12):
        R, T = km.layer_R0_T(3.0, 0.0, X)
        assert R == pytest.approx(3 * X / (1 + 3 * X), rel=1e-13)
        assert T == pytest.approx(1 / (1 + 3 * X), rel=1e-13)
        assert R + T == pytest.approx(1.0, abs=1e-15)
    assert km.layer_R0_T(3.0, 0.0, np.inf) == (1.0, 0.0)
    # S → 0: R0 → 0, T → exp(−KX) (Beer–Lambert)
    for S_ in (0.0, 1e-12):
        R, T = km.layer_R0_T(S_, 2.0, 0.7)
        assert R == pytest.approx(S_ * (1 - np.exp(-2.8)) / 4, abs=1e-20)
        assert T == pytest.approx(np.exp(-1.4), rel=1e-10)
    # vacuum, even infinitely thick
    assert km.layer_R0_T(0.0, 0.0, np.inf) == (0.0, 1.0)
    # no NaN/Inf/overflow warnings anywhere on a wide grid
    g = np.array([0.0, 1e-300, 1e-12, 1e-3, 1.0, 1e3, 1e12])
    with np.errstate(divide="raise", over="raise", invalid="raise"):
        R, T = km.layer_R0_T(g[:, None, None], g[None, :, None], np.append(g, np.inf)[None, None, :])
    assert np.isfinite(R).all() and np.isfinite(T).all()
    assert ((R >= 0) & (R <= 1) & (T >= 0) & (T <= 1) & (R + T <= 1 + 1e-12)).all()


def test_stack_is_order_dependent_but_consistent():
    rng = np.random.default_rng(4)
    S, K, X = rng.uniform(0, 20, (3, 50)), rng.uniform(0, 5, (3, 50)), rng.uniform(0, 0.2, (3, 1))
    Rt, Rb, T = km.stack(list(S), list(K), list(X))
    # reversing the stack swaps the reflectances from above and below, T is symmetric
    Rt2, Rb2, T2 = km.stack(list(S[::-1]), list(K[::-1]), list(X[::-1]))
    np.testing.assert_allclose(Rt2, Rb, rtol=1e-12)
    np.testing.assert_allclose(Rb2, Rt, rtol=1e-12)
    np.testing.assert_allclose(T2, T, rtol=1e-12)
    # stack over a background = background treated as a last (opaque) layer of that reflectance
    Rg = rng.uniform(0, 1, 50)
    R = km.over_background(Rt, Rb, T, Rg)
    R_seq = Rg
    for i in range(3):
        R_seq = km.reflectance_over(S[i], K[i], X[i], R_seq)
    np.testing.assert_allclose(R, R_seq, rtol=1e-12)


@settings(max_examples=300, deadline=None)
@given(S=st.floats(0.05, 100.0), K=st.floats(1e-3, 50.0), D=st.floats(0.01, 0.5), Rg=st.floats(0.0, 0.95))
def test_invert_round_trips(S, K, D, Rg):
    R = km.reflectance_over(S, K, D, Rg)
    Ri = km.r_infinity(S, K)
    if abs(R - Ri) < 1e-6 or abs(R - Rg) < 1e-6:
        return  # the measurement carries no information (opaque or invisible layer)
    assert km.check_invert_inputs(R, Rg, Ri) is None
    S2, K2 = km.invert(R, Rg, Ri, D)
    assert S2 == pytest.approx(S, rel=1e-9) and K2 == pytest.approx(K, rel=1e-9)


def test_invert_well_conditioned_grid_to_1e9():
    rng = np.random.default_rng(7)
    S, K = rng.uniform(0.5, 40, 5000), rng.uniform(0.01, 10, 5000)
    D, Rg = 0.15, rng.uniform(0, 0.9, 5000)
    R, Ri = km.reflectance_over(S, K, D, Rg), km.r_infinity(S, K)
    S2, K2 = km.invert(R, Rg, Ri, D)
    assert np.abs(S2 / S - 1).max() < 1e-9 and np.abs(K2 / K - 1).max() < 1e-9
    # no absorption: R∞ = 1
    S2, K2 = km.invert(km.reflectance_over(4.0, 0.0, D, 0.2), 0.2, 1.0, D)
    assert S2 == pytest.approx(4.0, rel=1e-12) and K2 == 0.0


def test_invert_refuses_bad_measurements():
    assert km.check_invert_inputs(0.5, 0.0, 0.4)[0] == "R"        # R∞ ≤ R over black
    assert km.check_invert_inputs(0.4, 0.0, 0.4)[0] == "R"
    assert km.check_invert_inputs(1.2, 0.0, 0.4)[0] == "R"        # out of [0, 1]
    assert km.check_invert_inputs(0.2, -0.1, 0.4)[0] == "Rg"
    assert km.check_invert_inputs(0.2, 0.0, 0.0)[0] == "Rinf"
    assert km.check_invert_inputs(0.1, 0.3, 0.5)[0] == "R"        # not between Rg and R∞
    assert km.check_invert_inputs(0.2, 0.0, 0.4) is None


def test_lookup_exact_on_nodes_and_close_between():
    rng = np.random.default_rng(3)
    wl = km.WAVELENGTHS
    S, K = rng.uniform(1, 30, (3, wl.size)), rng.uniform(0.1, 8, (3, wl.size))
    grids = km.thickness_grid([0.03, 0.05, 0.0], 17)
    tabs = km.stack_rgb_table(S, K, wl, grids, "D65", None)
    h, w = 16, 20
    # thicknesses exactly on nodes (binary masks × thickness) → table values, exactly
    t = np.stack([0.03 * (rng.random((h, w)) > 0.5), 0.05 * (rng.random((h, w)) > 0.5), np.zeros((h, w))], -1)
    t = t.astype(np.float32)
    outs = km.lookup(tabs, grids, t)
    W = km.rgb_weights(wl)
    Wf = W / W.sum(axis=0)  # transmittances are RGB filters
    Rt, Rb, T = km.stack(list(S), list(K), [t[..., i:i + 1].astype(np.float64) for i in range(3)])
    np.testing.assert_allclose(outs[0], Rt @ W, atol=2e-7)
    np.testing.assert_allclose(outs[2], T @ Wf, atol=2e-7)
    # soft thicknesses: multilinear interpolation error of the 17-node grid
    t = np.stack([0.03 * rng.random((h, w)), 0.05 * rng.random((h, w)), np.zeros((h, w))], -1).astype(np.float32)
    outs = km.lookup(tabs, grids, t)
    Rt, Rb, T = km.stack(list(S), list(K), [t[..., i:i + 1].astype(np.float64) for i in range(3)])
    assert np.abs(outs[0] - Rt @ W).max() < 2e-3
    assert np.abs(outs[2] - T @ Wf).max() < 2e-3


def test_lookup_hits_nodes_exactly_for_any_thickness():
    # t = max must land on the last node even when max·(N−1)/max rounds below N−1 in float32
    rng = np.random.default_rng(8)
    for m in rng.uniform(0.001, 0.5, 40).astype(np.float32):
        g = km.thickness_grid([float(m)], 25)
        table = np.arange(25, dtype=np.float32)[:, None] * np.ones(3, np.float32)
        t = np.array([[[0.0], [m], [m]]], np.float32)
        out = km.lookup(table, g, t)
        np.testing.assert_array_equal(out[0, :, 0], [0.0, 24.0, 24.0])


def test_lookup_snapped_axis_with_an_interpolated_one():
    # one axis a hair below its last node (snapped), the other between nodes: stays in bounds
    g = km.thickness_grid([1.0, 1.0], 5)
    table = (np.arange(5)[:, None] * 10 + np.arange(5)[None, :]).astype(np.float32)[..., None]
    t = np.array([[[np.nextafter(np.float32(1), np.float32(0)), 0.3]]], np.float32)
    out = km.lookup(table, g, t)
    assert out[0, 0, 0] == pytest.approx(40 + 0.3 * 4, abs=1e-4)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(["zero", "max", "below_max", "near_node", "random"]), min_size=24, max_size=24),
       st.integers(0, 2**31 - 1))
def test_lookup_mixed_maps_match_exact_stack(kinds, seed):
    rng = np.random.default_rng(seed)
    wl = km.WAVELENGTHS
    S, K = rng.uniform(1, 30, (3, wl.size)), rng.uniform(0.1, 8, (3, wl.size))
    mx = rng.uniform(0.005, 0.1, 3).astype(np.float32)
    vals = np.zeros((4, 6, 3), np.float32)
    for k, kind in enumerate(kinds):
        y, x = divmod(k, 6)
        for i in range(3):
            v = {"zero": 0.0, "max": mx[i], "below_max": np.nextafter(mx[i], np.float32(0)),
                 "near_node": mx[i] * rng.integers(0, 25) / 24 * (1 + 1e-7 * rng.normal()),
                 "random": mx[i] * rng.random()}[kind if i != k % 3 else "random"]
            vals[y, x, i] = min(np.float32(v), mx[i])
    vals[0, 0] = mx  # the map's maxima are the grid ends
    g = km.thickness_grid([float(vals[..., i].max()) for i in range(3)], 25)
    tabs = km.stack_rgb_table(S, K, wl, g, "D65", None)
    out = km.lookup(tabs, g, vals)
    Rt, Rb, T = km.stack(list(S), list(K), [vals[..., i:i + 1].astype(np.float64) for i in range(3)])
    assert np.abs(out[0] - Rt @ km.rgb_weights(wl)).max() < 2e-3


def _multilinear_f64(table, grids, t):
    """Plain float64 multilinear interpolation of table (*sizes, C) at thicknesses t (…, n):
    a loop over the 2^n corners, thicknesses clamped to each grid, and (as km.lookup documents)
    a coordinate within km.SNAP of a node put on it."""
    sizes = [len(g) for g in grids]
    t = np.asarray(t, np.float64)
    lo, wt = [], []
    for i, (g, N) in enumerate(zip(grids, sizes)):
        if N == 1:
            lo.append(np.zeros(t.shape[:-1], np.int64))
            wt.append(np.zeros(t.shape[:-1]))
            continue
        f = np.clip(t[..., i], g[0], g[-1]) / (g[-1] - g[0]) * (N - 1)
        f = np.where(np.abs(f - np.rint(f)) <= km.SNAP, np.rint(f), f)
        i0 = np.minimum(np.floor(f).astype(np.int64), N - 2)
        lo.append(i0)
        wt.append(f - i0)
    out = 0.0
    for corner in range(1 << len(sizes)):
        idx, w = [], 1.0
        for i, N in enumerate(sizes):
            b = corner >> i & 1
            if N == 1 and b:
                w = w * 0.0
            idx.append(np.minimum(lo[i] + b, N - 1))
            w = w * (wt[i] if b else 1.0 - wt[i])
        out = out + np.asarray(table, np.float64)[tuple(idx)] * np.asarray(w)[..., None]
    return out


@pytest.mark.parametrize("sizes, shape", [((25, 25, 25), (96, 700)), ((17, 1, 9), (40, 50)), ((33,), (30, 40)),
                                          ((5, 7), (300, 200)), ((9, 9, 9, 5), (20, 30))])
def test_lookup_matches_float64_multilinear(sizes, shape):
    """The cv2.remap gathers and the per-cell coefficient form against a plain float64
    multilinear reference: exact on nodes, float32 rounding between them, bands that are on
    nodes, mostly off them, or mixed (an image wider than one band)."""
    rng = np.random.default_rng(len(sizes) * 100 + sizes[0])
    n = len(sizes)
    mx = rng.uniform(0.01, 0.2, n)
    grids = [np.linspace(0, m, N) if N > 1 else np.zeros(1) for m, N in zip(mx, sizes)]
    tabs = [rng.uniform(0, 1, sizes + (3,)).astype(np.float32), rng.uniform(-2, 2, sizes + (1,)).astype(np.float32)]
    h, w = shape
    nodes = np.stack([rng.integers(0, N, (h, w)) * (g[-1] / max(N - 1, 1)) for g, N in zip(grids, sizes)], -1)
    soft = rng.uniform(0, 1, (h, w, n)) * np.array([g[-1] for g in grids])
    t = nodes.copy()
    t[: h // 3] = soft[: h // 3]                                    # top: every pixel between nodes
    sprinkle = rng.random((h, w)) < 0.05
    t[h // 3:][sprinkle[h // 3:]] = soft[h // 3:][sprinkle[h // 3:]]  # below: 5 % between nodes
    t[-1, -1] = [g[-1] * 1.5 for g in grids]                        # beyond the grid: clamped
    t = t.astype(np.float32)
    got = km.lookup(tabs, grids, t)
    for tab, out in zip(tabs, got):
        ref = _multilinear_f64(tab, grids, t)
        assert out.dtype == np.float32 and out.shape == (h, w, tab.shape[-1])
        # float32 cell positions: ~1e-6 cells; the rest is float32 rounding
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5 * np.abs(tab).max())
    # pixels on nodes (bottom part, outside the sprinkle) are the table entries, bit for bit
    on = np.zeros((h, w), bool)
    on[h // 3:] = ~sprinkle[h // 3:]
    on[-1, -1] = False
    k = [np.rint(nodes[..., i] / (g[-1] / max(N - 1, 1)) if N > 1 else 0 * nodes[..., i]).astype(int)
         for i, (g, N) in enumerate(zip(grids, sizes))]
    for tab, out in zip(tabs, got):
        np.testing.assert_array_equal(out[on], tab[tuple(ki[on] for ki in k)])


def test_float32_inputs_are_computed_in_float64():
    """(mutants that dropped dtype=np.float64 survived) float32 coefficients give the float64
    result of the same values, not a float32 one."""
    S32, K32, X32 = np.float32([0.9, 30.6, 3.3]), np.float32([0.757, 10.7, 1e-3]), np.float32([0.03, 0.2, 7.0])
    S, K, X = (v.astype(np.float64) for v in (S32, K32, X32))
    for got, want in ((km.layer_R0_T(S32, K32, X32), km.layer_R0_T(S, K, X)),
                      ((km.r_infinity(S32, K32),), (km.r_infinity(S, K),))):
        for g, w in zip(got, want):
            assert g.dtype == np.float64
            np.testing.assert_array_equal(g, w)


def test_empty_stack_is_vacuum():
    Rt, Rb, T = km.stack([], [], [])
    for v, want in ((Rt, 0.0), (Rb, 0.0), (T, 1.0)):
        assert v.shape == (1,) and v[0] == want


@settings(max_examples=25, deadline=None)
@given(st.lists(st.sampled_from(["zero", "max", "below_node", "near_node", "random", "cell"]), min_size=3, max_size=3),
       st.integers(0, 2**31 - 1), st.sampled_from([3, 4]))
def test_lazy_tables_look_up_the_bytes_of_whole_tables(kinds, seed, n):
    # stack_rgb_table(full=False) computes the lines of nodes a lookup reads as maps come (each
    # small map here needs lines the ones before did not; their interpolation coefficients are
    # made for those lines only): the same bytes as through the whole table
    rng = np.random.default_rng(seed)
    wl = km.WAVELENGTHS
    S, K = rng.uniform(1, 30, (n, wl.size)), rng.uniform(0.1, 8, (n, wl.size))
    mx = rng.uniform(0.005, 0.1, n).astype(np.float32)
    g = km.thickness_grid([float(m) for m in mx], 25)
    bg = rng.uniform(0, 1, wl.size) if seed % 2 else None
    km._TABLES.clear()
    whole = km.stack_rgb_table(S, K, wl, g, "D65", bg)
    km._TABLES.clear()
    lazy = km.stack_rgb_table(S, K, wl, g, "D65", bg, full=False)
    for kind in [*kinds, "some"]:  # (some: pixels on nodes but one, interpolated apart from the band)
        node = rng.integers(0, 25, (2, 3, n)).astype(np.float32)
        some = node.copy()
        some[0, 0] += rng.random(n).astype(np.float32)
        t = {"zero": np.zeros((2, 3, n)), "max": np.broadcast_to(mx, (2, 3, n)),
             "below_node": mx * np.nextafter(node / 24, np.float32(0)),  # snapped up to the node
             "near_node": mx * node / 24 * (1 + 1e-7 * rng.normal(size=node.shape)),
             "random": mx * rng.random((2, 3, n)), "cell": mx * (node + rng.random((2, 3, n))) / 24,
             "some": mx * some / 24}[kind]
        t = np.minimum(np.asarray(t, np.float32), mx)
        for a, b in zip(km.lookup(whole, g, t), km.lookup(lazy, g, t)):
            np.testing.assert_array_equal(a, b)
    assert not lazy.done.all()
    km._TABLES.clear()
