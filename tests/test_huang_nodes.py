"""Huang 2013 nodes: KMLayer, KMInvert, CosmeticMap, KMStack, CosmeticShade; library; bad input."""
from __future__ import annotations

import csv
import inspect
from pathlib import Path

import numpy as np
import pytest

from graphkit import BadInput, Context, Image, Light, Mask, Spectrum
from nodes.common.microfacet import kelemen_specular
from nodes.huang import km
from nodes.huang.layer import CosmeticMap, KMInvert, KMLayer
from nodes.huang.library import cosmetic_names, get_cosmetic, layer_arrays, load_library, skin_spectrum
from nodes.huang.shade import CosmeticShade
from nodes.huang.stack import KMStack

pytestmark = pytest.mark.filterwarnings("ignore:Aligning:Warning", "ignore:Trimming:Warning", "ignore::UserWarning")
DATA = Path(__file__).resolve().parents[1] / "nodes" / "huang" / "data"
SET3 = ["foundation_light", "blush_rose", "lipstick_red"]


def run(cls, inputs=None, ctx=None, **params):
    """Run a node as the engine does: its declared port constraints, then compute."""
    from graphkit.contract import compute_checked

    return compute_checked(cls(cls.Params(**params), ctx or Context()), **(inputs or {}))


# --------------------------------------------------------------------------------------------
# library


def test_library_is_documented_examples_derived_by_kminvert():
    lib = load_library()
    assert "not measured products" in lib["description"].lower() or "examples" in lib["description"].lower()
    import colour

    shape = colour.SpectralShape(380, 780, 5)
    for name in cosmetic_names():
        c = lib["cosmetics"][name]
        csv_path = DATA / "samples" / f"{name}.csv"
        # the library's S, K are what KMInvert gives for the sample CSV
        res = run(KMInvert, path=str(csv_path), thickness_mm=lib["sample_thickness_mm"])
        np.testing.assert_allclose(c["S_per_mm"], res["S"].values, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(c["K_per_mm"], res["K"].values, rtol=1e-9, atol=1e-11)
        # and an opaque layer of it reflects the measured ColorChecker spectrum (outside data)
        patch = c["source"].split("'")[1]
        rinf = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"][patch].copy().align(shape).values
        np.testing.assert_allclose(km.r_infinity(np.array(c["S_per_mm"]), np.array(c["K_per_mm"])), rinf, rtol=1e-9)


def test_unknown_cosmetic_is_bad_input():
    with pytest.raises(BadInput) as e:
        get_cosmetic("lipstik_red")
    assert e.value.port == "cosmetics" and "lipstick_red" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": Image(np.zeros((2, 2, 1)))}, cosmetics=["nope"])
    assert e.value.port == "cosmetics" and "unknown cosmetic 'nope'" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMLayer, cosmetic="nope")
    assert e.value.port == "cosmetic"


# --------------------------------------------------------------------------------------------
# KMLayer / KMInvert


def test_kmlayer_outputs():
    res = run(KMLayer, cosmetic="lipstick_red", thickness_mm=0.04)
    spec = get_cosmetic("lipstick_red")
    R0, T = km.layer_R0_T(np.array(spec.S), np.array(spec.K), 0.04)
    np.testing.assert_array_equal(res["R0"].values, R0)
    np.testing.assert_array_equal(res["T"].values, T)
    np.testing.assert_allclose(res["R0_rgb"].pixels[0, 0], km.spectral_to_rgb(R0, res["R0"].wavelengths), atol=1e-6)
    assert res["layer"].thickness_mm == 0.04 and res["layer"].name == "lipstick_red"
    # thickness map: per pixel, exact at grid nodes (0 and max) and close in between
    t = np.array([[0.0, 0.01, 0.04]], np.float32)[..., None]
    res = run(KMLayer, {"thickness": Image(t)}, cosmetic="lipstick_red", illuminant="A")
    for x, d in enumerate((0.0, 0.01, 0.04)):
        R0, T = km.layer_R0_T(np.array(spec.S), np.array(spec.K), float(np.float32(d)))
        np.testing.assert_allclose(res["T_rgb"].pixels[0, x], km.spectral_to_rgb(T, km.WAVELENGTHS, "A"), atol=1e-4)
    np.testing.assert_allclose(res["T_rgb"].pixels[0, 0], km.spectral_to_rgb(np.ones(81), km.WAVELENGTHS, "A"), atol=1e-6)


def test_kmlayer_from_spectra_and_bad_coefficients():
    wl = np.arange(400.0, 701.0, 10.0)
    S, K = Spectrum(wl, np.full(wl.size, 5.0)), Spectrum(wl, np.linspace(0.1, 2, wl.size))
    res = run(KMLayer, {"S": S, "K": K}, thickness_mm=0.1, name="mine")
    np.testing.assert_array_equal(res["R0"].values, km.layer_R0_T(5.0, K.values, 0.1)[0])
    assert res["layer"].name == "mine"
    bad = Spectrum(wl, np.where(wl == 550, -0.5, 1.0))
    with pytest.raises(BadInput) as e:
        run(KMLayer, {"S": bad, "K": K})
    assert e.value.port == "S" and "≥ 0" in e.value.message and "550" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMLayer, {"S": S, "K": Spectrum(wl, -K.values)})
    # the port's declared constraint (graphkit.contract) words it: the port is K
    assert e.value.port == "K" and "must be ≥ 0" in e.value.message and "(min -2), the first at 400 nm" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMLayer, {"S": S})
    assert e.value.port == "K" and e.value.message == "connect both S and K (or neither, to use 'cosmetic')"
    with pytest.raises(BadInput) as e:
        run(KMLayer, {"S": S, "K": K}, cosmetic="lipstick_red")
    assert e.value.port == "cosmetic" and e.value.message == "S and K are connected: leave 'cosmetic' empty"
    with pytest.raises(BadInput) as e:
        run(KMLayer)
    assert e.value.port == "cosmetic" and e.value.message == "connect S and K, or name a library cosmetic"
    with pytest.raises(BadInput) as e:
        run(KMLayer, cosmetic="lipstick_red", illuminant="D66")
    assert e.value.port == "illuminant"


def _write_csv(path, wl, R, Rg, Ri):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["wavelength", "R", "Rg", "Rinf"])
        for row in zip(wl, R, Rg, Ri):
            w.writerow([repr(float(x)) for x in row])


def test_kminvert_round_trips_from_csv_and_spectra(tmp_path):
    rng = np.random.default_rng(11)
    wl = km.WAVELENGTHS
    S, K = rng.uniform(1, 40, wl.size), rng.uniform(0.05, 8, wl.size)
    D = 0.15
    for Rg in (np.zeros(wl.size), rng.uniform(0.05, 0.6, wl.size)):
        R, Ri = km.reflectance_over(S, K, D, Rg), km.r_infinity(S, K)
        _write_csv(tmp_path / "m.csv", wl, R, Rg, Ri)
        res = run(KMInvert, path="m.csv", thickness_mm=D, ctx=Context(base_dir=str(tmp_path)))
        np.testing.assert_allclose(res["S"].values, S, rtol=1e-9)
        np.testing.assert_allclose(res["K"].values, K, rtol=1e-9)
        res2 = run(KMInvert, {"R": Spectrum(wl, R), "Rg": Spectrum(wl, Rg), "Rinf": Spectrum(wl, Ri)}, thickness_mm=D)
        np.testing.assert_allclose(res2["K"].values, K, rtol=1e-9)
        # and the layer goes back through KMLayer to the same R over the background
        lay = run(KMLayer, {"S": res["S"], "K": res["K"]}, thickness_mm=D)
        np.testing.assert_allclose(km.over_background(lay["R0"].values, lay["R0"].values, lay["T"].values, Rg), R,
                                   rtol=1e-12)


def test_kminvert_bad_measurements(tmp_path):
    wl = km.WAVELENGTHS
    Ri = np.full(wl.size, 0.4)
    z = np.zeros(wl.size)
    # R∞ ≤ R over a black background
    R = np.full(wl.size, 0.3)
    R[10] = 0.45
    with pytest.raises(BadInput) as e:
        run(KMInvert, {"R": Spectrum(wl, R), "Rg": Spectrum(wl, z), "Rinf": Spectrum(wl, Ri)})
    assert e.value.port == "R" and "R < R∞" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMInvert, {"R": Spectrum(wl, R), "Rinf": Spectrum(wl, Ri)})
    assert e.value.port == "Rg" and e.value.message == "connect all of R, Rg and Rinf (or none, to use 'path')"
    with pytest.raises(BadInput) as e:
        run(KMInvert, {"R": Spectrum(wl, R), "Rg": Spectrum(wl, z), "Rinf": Spectrum(wl, Ri)}, path="m.csv")
    assert e.value.port == "path" and e.value.message == "R, Rg and Rinf are connected: leave 'path' empty"
    with pytest.raises(BadInput) as e:
        run(KMInvert)
    assert e.value.port == "path" and e.value.message == "connect R, Rg and Rinf, or give a CSV path"
    with pytest.raises(BadInput) as e:
        run(KMInvert, {"R": Spectrum(wl, R), "Rg": Spectrum(wl, z), "Rinf": Spectrum(wl + 1, Ri)})
    assert e.value.port == "Rinf" and e.value.message == "R, Rg and Rinf must be sampled at the same wavelengths"
    # reflectance outside [0, 1], from a CSV: the path param is named
    R2 = R.copy()
    R2[3] = 1.3
    _write_csv(tmp_path / "bad.csv", wl, R2, z, Ri)
    with pytest.raises(BadInput) as e:
        run(KMInvert, path=str(tmp_path / "bad.csv"))
    assert e.value.port == "path" and "[0, 1]" in e.value.message
    (tmp_path / "cols.csv").write_text("wavelength,R,Rinf\n400,0.1,0.2\n410,0.1,0.2\n")
    with pytest.raises(BadInput) as e:
        run(KMInvert, path=str(tmp_path / "cols.csv"))
    assert "no column 'rg'" in e.value.message
    with pytest.raises(BadInput):
        run(KMInvert, path=str(tmp_path / "missing.csv"))


# --------------------------------------------------------------------------------------------
# CosmeticMap / KMStack


def test_cosmetic_map():
    a = np.zeros((4, 5), np.float32)
    a[1:3, 1:4] = 1
    b = np.ones((4, 5), np.float32) * 0.5
    ex = np.zeros((4, 5), np.float32)
    ex[0, 0] = 1
    t = run(CosmeticMap, {"regions": [Mask(a), Mask(b)], "exclude": Mask(ex)}, thickness_mm=[0.02, 0.04])
    assert t.pixels.shape == (4, 5, 2)
    np.testing.assert_allclose(t.pixels[..., 0], a * 0.02, rtol=1e-6)
    assert t.pixels[0, 0, 1] == 0 and t.pixels[3, 4, 1] == pytest.approx(0.02)
    with pytest.raises(BadInput) as e:
        run(CosmeticMap, {"regions": [Mask(a), Mask(np.ones((3, 5)))]}, thickness_mm=[0.02, 0.04])
    assert e.value.port == "regions"
    with pytest.raises(BadInput) as e:
        run(CosmeticMap, {"regions": [Mask(a)]}, thickness_mm=[0.02, 0.04])
    assert e.value.port == "thickness_mm"


def test_kmstack_equals_spectral_stack_and_limits():
    wl, S, K = layer_arrays([get_cosmetic(n) for n in SET3])
    skin = skin_spectrum(wl)
    t = np.array([[[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [0.03, 0.02, 0.0], [0.03, 0.02, 0.05]]], np.float32)
    out = run(KMStack, {"thickness": Image(t)}, cosmetics=SET3)
    for x in range(4):
        Rt, Rb, T = km.stack(list(S), list(K), [float(v) for v in t[0, x]])
        np.testing.assert_allclose(out["reflectance"].pixels[0, x],
                                   km.spectral_to_rgb(km.over_background(Rt, Rb, T, skin), wl), atol=2e-6)
        white = km.spectral_to_rgb(np.ones(wl.size), wl)
        np.testing.assert_allclose(out["transmittance"].pixels[0, x], km.spectral_to_rgb(T, wl) / white, atol=2e-6)
    # no makeup = the skin; the layers from KMLayer nodes = the same as by name
    np.testing.assert_allclose(out["reflectance"].pixels[0, 0], km.spectral_to_rgb(skin, wl), atol=2e-6)
    layers = [run(KMLayer, cosmetic=n)["layer"] for n in SET3]
    out2 = run(KMStack, {"thickness": Image(t), "layers": layers})
    np.testing.assert_array_equal(out2["reflectance"].pixels, out["reflectance"].pixels)
    # a very thick top layer hides everything below: R = RGB of its R∞
    t_thick = np.array([[[0.03, 0.02, 50.0]]], np.float32)
    out = run(KMStack, {"thickness": Image(t_thick)}, cosmetics=SET3)
    np.testing.assert_allclose(out["reflectance"].pixels[0, 0], km.spectral_to_rgb(km.r_infinity(S[2], K[2]), wl), atol=2e-6)
    assert np.abs(out["transmittance"].pixels).max() < 1e-6


def test_kmstack_rgb_background_formula():
    t = np.zeros((3, 4, 3), np.float32)
    t[1:, :, 0] = 0.03
    t[:, 2:, 2] = 0.05
    rho = np.random.default_rng(2).uniform(0.1, 0.8, (3, 4, 3)).astype(np.float32)
    out = run(KMStack, {"thickness": Image(t), "background": Image(rho)}, cosmetics=SET3)
    np.testing.assert_array_equal(out["reflectance"].pixels[0, :2], rho[0, :2])  # bare skin stays, exactly
    wl, S, K = layer_arrays([get_cosmetic(n) for n in SET3])
    W = km.rgb_weights(wl)
    white = km.spectral_to_rgb(np.ones(wl.size), wl)
    Rt, Rb, T = km.stack(list(S), list(K), [float(v) for v in t[2, 3]])
    want = Rt @ W + ((T * T) @ W / white) * rho[2, 3] / (1 - (Rb @ W / white) * rho[2, 3])
    np.testing.assert_allclose(out["reflectance"].pixels[2, 3], want, atol=2e-6)


def test_kmstack_bad_input():
    t = Image(np.zeros((4, 5, 3), np.float32))
    neg = get_cosmetic("blush_rose").model_copy(update={"K": [-1.0] + get_cosmetic("blush_rose").K[1:]})
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": Image(np.zeros((4, 5, 1))), "layers": [neg]})
    assert e.value.port == "layers" and "K must be ≥ 0" in e.value.message and "380 nm" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": t, "background": Image(np.zeros((4, 6, 3)))}, cosmetics=SET3)
    assert e.value.port == "thickness" and "5×4" in e.value.message and "6×4" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": t}, cosmetics=SET3[:2])
    assert e.value.port == "thickness" and "3 channels but there are 2 layers" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": Image(-np.ones((4, 5, 3)))}, cosmetics=SET3)
    assert e.value.port == "thickness" and "≥ 0" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": t, "background": Image(np.full((4, 5, 3), 1.5))}, cosmetics=SET3)
    assert e.value.port == "background" and "[0, 1]" in e.value.message
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": t, "background_spectrum": Spectrum(km.WAVELENGTHS, np.full(81, -0.1))},
            cosmetics=SET3)
    assert e.value.port == "background_spectrum"
    nan = np.zeros((4, 5, 3), np.float32)
    nan[1, 1, 1] = np.nan
    with pytest.raises(BadInput) as e:
        run(KMStack, {"thickness": Image(nan)}, cosmetics=SET3)
    assert "NaN" in e.value.message


# --------------------------------------------------------------------------------------------
# CosmeticShade


def test_cosmetic_shade_uses_the_shared_sss_and_microfacet():
    from nodes.common import sss

    from nodes.huang import shade

    # compute's diffuse part (CosmeticShade._diffuse) and specular part (shade._specular)
    src = inspect.getsource(CosmeticShade._diffuse)
    assert CosmeticShade.sss_blur is sss.sss_blur and "self.sss_blur(" in src  # the hook backends replace
    # the profile with its faint channel weights folded (tests/test_sss.py), on both paths
    assert shade.PROFILE == sss.fold_faint() and "profile=PROFILE" in src
    assert "surf.depth, PROFILE, mask=" in inspect.getsource(CosmeticShade._fixed)
    assert "from nodes.common.microfacet import kelemen_specular" in inspect.getsource(shade._specular)


def test_cosmetic_shade_uniform_light_equals_kmstack():
    h, w = 12, 14
    t = np.zeros((h, w, 3), np.float32)
    t[..., 0] = 0.03
    t[..., 1] = 0.02
    rho = np.full((h, w, 3), [0.55, 0.38, 0.3], np.float32)
    E = np.full((h, w, 3), [2.0, 1.5, 1.0], np.float32)
    ref = run(KMStack, {"thickness": Image(t), "background": Image(rho)}, cosmetics=SET3)["reflectance"].pixels
    for sss in (False, True):  # SSS of a uniform irradiance is the identity
        out = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "irradiance": Image(E)},
                  cosmetics=SET3, sss=sss, mm_per_pixel=0.5)
        np.testing.assert_allclose(out["diffuse"].pixels, ref * E, rtol=1e-5, atol=1e-6)
        assert (out["specular"].pixels == 0).all()


def test_cosmetic_shade_sss_blurs_only_the_transmitted_light():
    h, w = 24, 40
    t = np.zeros((h, w, 1), np.float32)
    t[:, w // 2:, 0] = 0.05  # lipstick on the right half
    rho = np.full((h, w, 3), 0.5, np.float32)
    a = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t)}, cosmetics=["lipstick_red"], sss=False)
    b = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t)}, cosmetics=["lipstick_red"], sss=True,
            mm_per_pixel=2.0)  # widest profile Gaussian: σ = 2.7 mm = 1.4 px
    d = np.abs(a["diffuse"].pixels - b["diffuse"].pixels).max(axis=(0, 2))
    assert d[: w // 2 - 12].max() < 1e-5 and d[w // 2 + 12:].max() < 1e-5  # far from the edge: unchanged
    assert d[w // 2 - 2: w // 2 + 2].max() > 1e-3                           # at the edge: light bleeds


def test_cosmetic_shade_specular_bottom_to_top():
    h, w = 3, 4
    rng = np.random.default_rng(9)
    n = rng.normal(size=(h, w, 3)) * 0.2 + [0, 0, -1]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    light = Light(direction=(0.2, -0.3, -1.0), intensity=1.5, color=(1.0, 0.9, 0.8))
    l = np.array(light.direction) / np.linalg.norm(light.direction)
    v = np.array([0.0, 0.0, -1.0])
    rho = np.full((h, w, 3), 0.5, np.float32)
    t = np.zeros((h, w, 2), np.float32)
    t[:, 2:, 0] = 0.03
    t[1:, :, 1] = 0.05
    names = ["foundation_light", "lipstick_red"]
    out = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "normals": Image(n), "light": light},
              cosmetics=names, cover_mm=0.005)
    specs = [get_cosmetic(x) for x in names]
    wl, S, K = layer_arrays(specs)
    W = km.rgb_weights(wl)
    lc = np.array(light.color) * light.intensity
    for y in range(h):
        for x in range(w):
            s = kelemen_specular(n[y, x], l, v, 0.35, 0.18, 0.028) * np.ones(3)
            for i, L in enumerate(specs):
                d = float(t[y, x, i])
                Ti = km.layer_R0_T(S[i], K[i], d)[1] @ W / W.sum(axis=0)
                s = s * Ti + min(1.0, d / 0.005) * kelemen_specular(n[y, x], l, v, L.m, L.rho_s, L.f0)
            np.testing.assert_allclose(out["specular"].pixels[y, x], s * lc, rtol=1e-5, atol=1e-7)
    # irradiance from normals and light: E = colour·intensity·max(N·L, 0) + ambient
    bare = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(np.zeros((h, w, 2), np.float32)),
                               "normals": Image(n), "light": light}, cosmetics=names, sss=False)
    E = np.maximum(n @ l, 0)[..., None] * lc
    np.testing.assert_allclose(bare["diffuse"].pixels, rho * E, rtol=1e-5, atol=1e-6)


def test_cosmetic_shade_bad_input():
    rho = Image(np.full((4, 5, 3), 0.5, np.float32))
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": rho, "thickness": Image(np.zeros((4, 4, 1)))}, cosmetics=["lipstick_red"])
    assert e.value.port == "thickness"
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": Image(np.full((4, 5, 3), 2.0)), "thickness": Image(np.zeros((4, 5, 1)))},
            cosmetics=["lipstick_red"])
    assert e.value.port == "albedo"
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": rho, "thickness": Image(np.zeros((4, 5, 1))), "light": Light(kind="point")},
            cosmetics=["lipstick_red"])
    assert e.value.port == "light" and "CosmeticShade needs a directional light" in e.value.message
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": rho, "thickness": Image(np.zeros((4, 5, 1)))}, cosmetics=["lipstick"])
    assert e.value.port == "cosmetics"
    # each optional map has the albedo's size and its channels (declared on the port)
    t = Image(np.zeros((4, 5, 1)))
    for port, bad, needle in [("irradiance", Image(np.ones((4, 5, 2))), "needs 1 or 3 channels, got 2"),
                              ("irradiance", Image(np.ones((3, 5, 3))), "sizes differ: albedo is 5×4×3, irradiance is 5×3×3"),
                              ("irradiance", Image(-np.ones((4, 5, 1))), "must be ≥ 0"),
                              ("normals", Image(np.ones((4, 5, 1))), "needs 3 channels, got 1"),
                              ("depth", Image(np.ones((4, 6, 1))), "sizes differ: albedo is 5×4×3, depth is 6×4×1"),
                              ("skin", Mask(np.ones((4, 6), np.float32)), "sizes differ: albedo is 5×4×3, skin is 6×4")]:
        with pytest.raises(BadInput) as e:
            run(CosmeticShade, {"albedo": rho, "thickness": t, port: bad}, cosmetics=["lipstick_red"])
        assert e.value.port == port and needle in e.value.message, (port, e.value)


# --------------------------------------------------------------------------------------------
# through the CLI: a clear message naming node and port, exit 2, no traceback


def test_cli_bad_cosmetic_name(tmp_path):
    from conftest import graphkit

    g = tmp_path / "g.yaml"
    g.write_text("""graphkit: 1
name: bad
nodes:
  layer:
    type: KMLayer
    params: {cosmetic: lipstik_red}
outputs:
  r0: layer.R0
""")
    import os

    env = dict(os.environ)
    env.pop("GRAPHKIT_TRACEBACK", None)
    r = graphkit("run", g, "--out", tmp_path / "out", "--cache", tmp_path / "cache", env=env)
    assert r.returncode == 2, r.stderr
    assert "layer" in r.stderr and "cosmetic" in r.stderr and "lipstick_red" in r.stderr
    assert "Traceback" not in r.stderr


def test_cosmetic_shade_with_mesh_and_camera():
    """Normals, view rays and mm/pixel from a mesh: a plane facing the camera at 500 mm."""
    import trimesh

    from graphkit import Camera

    h, w = 16, 20
    cam = Camera(width=w, height=h, fx=40.0, fy=40.0, cx=w / 2, cy=h / 2)
    z = 500.0
    V = np.array([[-400, -400, z], [400, -400, z], [400, 400, z], [-400, 400, z]], float)
    mesh = trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False)
    light = Light(direction=(0.1, -0.2, -1.0), intensity=2.0)
    rho = np.full((h, w, 3), 0.5, np.float32)
    t = np.zeros((h, w, 1), np.float32)
    out = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "mesh": mesh, "camera": cam,
                              "light": light}, cosmetics=["foundation_light"], relight=False)
    l = np.array(light.direction) / np.linalg.norm(light.direction)
    y, x = 5, 13
    ray = np.array([(x + 0.5 - cam.cx) / cam.fx, (y + 0.5 - cam.cy) / cam.fy, 1.0])
    v = -ray / np.linalg.norm(ray)
    want = kelemen_specular(np.array([0, 0, -1.0]), l, v, 0.35, 0.18, 0.028) * 2.0
    np.testing.assert_allclose(out["specular"].pixels[y, x], want, rtol=1e-5)
    np.testing.assert_allclose(out["diffuse"].pixels, rho, rtol=1e-6)  # relight=False: unit irradiance
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "mesh": mesh},
            cosmetics=["foundation_light"])
    assert e.value.port == "camera" and e.value.message == "connect both mesh and camera (or neither)"
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "mesh": mesh,
                            "camera": cam.model_copy(update={"width": w + 1})}, cosmetics=["foundation_light"])
    assert e.value.port == "camera" and f"sizes differ: albedo is {w}×{h}×3, camera is {w + 1}×{h}" in e.value.message
    with pytest.raises(BadInput) as e:
        run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "mesh": mesh, "camera": cam,
                            "normals": Image(np.ones((h, w, 3)))}, cosmetics=["foundation_light"])
    assert e.value.port == "mesh" and "leave 'normals' and 'depth' unconnected" in e.value.message



def test_cosmetic_shade_boxes_and_memo_match_the_whole_frame():
    """CosmeticShade shades the box of the layers and the skin and keeps the surface, SSS plan
    and specular terms between calls: its output equals the whole-frame formula (the sss hook
    replaced by a plain sss_blur, which takes the whole-frame path) to float rounding, also for
    a second map and a second cosmetic set after the first call."""
    from nodes.common import sss
    from nodes.huang import shade

    h, w = 80, 100
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - 50) / 20.0) ** 2 + ((yy - 40) / 16.0) ** 2
    skin = Mask((r2 < 1).astype(np.float32))
    nrm = np.stack([(xx - 50) / 20.0, (yy - 40) / 16.0, -np.sqrt(np.clip(1 - r2, 0, 1))], -1) * (r2 < 1)[..., None]
    depth = Image((300.0 - 20 * np.sqrt(np.clip(1 - r2, 0, 1)))[..., None])
    rho = Image(np.clip(np.random.default_rng(2).random((h, w, 3)), 0.2, 0.9).astype(np.float32))
    light = Light(direction=(0.3, -0.2, -1.0), intensity=1.5)

    class WholeFrame(CosmeticShade):
        sss_blur = staticmethod(lambda *a, **k: sss.sss_blur(*a, **k))

    shade._FIXED.clear()
    prepared = []
    for cos, scale in ((["foundation_light", "blush_rose"], 1.0), (["foundation_light", "blush_rose"], 1.7),
                       (["foundation_dark", "blush_orange"], 1.0)):
        t = np.stack([0.02 * (r2 < 0.9), 0.03 * scale * (r2 < 0.3)], -1).astype(np.float32)
        ins = {"albedo": rho, "thickness": Image(t), "normals": Image(nrm), "depth": depth, "skin": skin,
               "light": light}
        got = run(CosmeticShade, ins, cosmetics=cos, mm_per_pixel=1.0, relight=False)
        ref = run(WholeFrame, ins, cosmetics=cos, mm_per_pixel=1.0, relight=False)
        assert np.array_equal(got["specular"].pixels, ref["specular"].pixels)
        np.testing.assert_allclose(got["diffuse"].pixels, ref["diffuse"].pixels, rtol=0, atol=1e-6)
        mine = [f for f in shade._FIXED.values() if f.scatter is not None]  # (WholeFrame's has none)
        prepared.append(id(mine[0]))
        out = ~np.isin(np.arange(h), np.arange(*mine[0].scatter.box[:2]))
        assert out.any() and np.array_equal(got["diffuse"].pixels[out], rho.pixels[out])  # ρ·E off the box
    assert prepared[0] == prepared[1]  # a new map on the same surface: prepared once


def test_cosmetic_shade_reshade_gives_the_bytes_of_a_fresh_frame(monkeypatch):
    """After a first frame on a surface, CosmeticShade blurs again only the rows around what
    changed (Scatter.update from the last light it scattered there): each frame has, bit for
    bit, the bytes of that frame shaded with nothing kept (a new blush thickness, a blush
    colour, the foundation thicker, the blush moved, a lipstick added)."""
    from nodes.common.sss import Scatter
    from nodes.huang import shade

    h, w = 150, 110
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - 55) / 40.0) ** 2 + ((yy - 75) / 60.0) ** 2  # a face taller than the widest kernel
    cheek = ((xx - 35) / 12.0) ** 2 + ((yy - 80) / 8.0) ** 2 < 1
    lips = ((xx - 55) / 14.0) ** 2 + ((yy - 115) / 5.0) ** 2 < 1
    ins = {"albedo": Image(np.clip(np.random.default_rng(5).random((h, w, 3)), 0.2, 0.9).astype(np.float32)),
           "normals": Image(np.stack([(xx - 55) / 40.0, (yy - 75) / 60.0, -np.sqrt(np.clip(1 - r2, 0, 1))], -1)
                            * (r2 < 1)[..., None]),
           "depth": Image((400.0 - 30 * np.sqrt(np.clip(1 - r2, 0, 1)))[..., None]),
           "skin": Mask((r2 < 1).astype(np.float32)), "light": Light(direction=(0.3, -0.2, -1.0))}

    def frame(cos, found=0.02, blush=0.03, shift=0, lip=0.0):
        t = np.stack([found * (r2 < 0.95), blush * np.roll(cheek, shift, axis=0), lip * lips], -1)
        return cos, Image(t.astype(np.float32))

    rose, orange = ["foundation_light", "blush_rose", "lipstick_red"], ["foundation_light", "blush_orange", "lipstick_red"]
    frames = [frame(rose), frame(rose, blush=0.045), frame(orange, blush=0.045), frame(orange, found=0.03),
              frame(orange, found=0.03, shift=-20), frame(orange, found=0.03, shift=-20, lip=0.05)]
    rows = []
    monkeypatch.setattr(Scatter, "_rows", lambda self, sub, out, r, f=Scatter._rows: (rows.append(r), f(self, sub, out, r)))
    shade._FIXED.clear()
    kept = [run(CosmeticShade, {**ins, "thickness": t}, cosmetics=cos, mm_per_pixel=0.5, relight=False) for cos, t in frames]
    again = rows[1:]
    for (cos, t), got in zip(frames, kept):
        shade._FIXED.clear()
        fresh = run(CosmeticShade, {**ins, "thickness": t}, cosmetics=cos, mm_per_pixel=0.5, relight=False)
        for k in ("image", "diffuse", "specular"):
            assert np.array_equal(got[k].pixels, fresh[k].pixels), k
    box = rows[0]  # the first frame: every row of the scatter's box
    assert len(again) == 5 and again[2] == box  # the foundation: every row again
    assert all(r[1] - r[0] < (box[1] - box[0]) * 0.7 for r in again[:2] + again[3:])  # the others: fewer


def test_cosmetic_shade_hashes_a_frozen_input_once_and_a_writeable_one_every_frame(monkeypatch):
    """CosmeticShade's memo of the surface (normals, depth, skin, light) is keyed by their
    digests: a read-only input (as the engine passes them) is hashed once and known again by its
    objects; normals changed in place (writeable) or replaced give the frame of the new normals."""
    from nodes.huang import shade

    params, ins = CosmeticShade.examples()[1]
    node = CosmeticShade(CosmeticShade.Params(**params))
    nrm = Image(ins["normals"].pixels.copy())
    hashed = []
    monkeypatch.setattr(shade, "value_parts", lambda t, v, f=shade.value_parts: (hashed.append(v), f(t, v))[1])

    def fresh(normals):
        shade._FIXED.clear()
        return node.compute(**{**ins, "normals": Image(normals.copy())})["specular"].pixels

    before = node.compute(**{**ins, "normals": nrm})["specular"].pixels
    nrm.pixels[:, :, :2] *= -1.0  # in place, writeable: hashed again, the new specular
    hashed.clear()
    got = node.compute(**{**ins, "normals": nrm})["specular"].pixels
    assert any(v is nrm for v in hashed) and not np.array_equal(got, before)
    assert np.array_equal(got, fresh(nrm.pixels))
    nrm.pixels.flags.writeable = False
    for _ in range(2):
        hashed.clear()
        node.compute(**{**ins, "normals": nrm})
    assert not any(v is nrm for v in hashed)  # frozen: known by its objects
    nrm.pixels = ins["normals"].pixels.copy()  # another array on the same Image: hashed
    nrm.pixels.flags.writeable = False
    hashed.clear()
    got = node.compute(**{**ins, "normals": nrm})["specular"].pixels
    assert any(v is nrm for v in hashed) and np.array_equal(got, before)


def test_cosmetic_shade_image_is_diffuse_plus_specular_bit_for_bit():
    """image = diffuse + specular, also where the specular is zero (an albedo of −0 gives +0
    there, as the sum does: the image is not a copy of the diffuse)."""
    h, w = 24, 32
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - 16) / 10.0) ** 2 + ((yy - 12) / 8.0) ** 2
    rho = np.full((h, w, 3), 0.5, np.float32)
    rho[0, 0] = -0.0  # off the skin's box: no normals, no specular, ρ·E kept as it is
    nrm = np.stack([(xx - 16) / 10.0, (yy - 12) / 8.0, -np.sqrt(np.clip(1 - r2, 0, 1))], -1) * (r2 < 1)[..., None]
    t = np.stack([0.02 * (r2 < 0.8)], -1).astype(np.float32)
    got = run(CosmeticShade, {"albedo": Image(rho), "thickness": Image(t), "normals": Image(nrm),
                              "skin": Mask((r2 < 1).astype(np.float32)), "light": Light(direction=(0.3, -0.2, -1.0))},
              cosmetics=["foundation_light"], relight=False, mm_per_pixel=5.0)  # (narrow kernels: off the SSS's box)
    want = got["diffuse"].pixels + got["specular"].pixels
    assert got["specular"].pixels.any() and np.signbit(got["diffuse"].pixels[0, 0]).all()
    assert np.array_equal(got["image"].pixels.view(np.uint32), want.view(np.uint32))


class _Studio:
    """What a live view reads of the studio: a loaded graph and given input values per node."""

    def __init__(self, graph_file, values: dict):
        from graphkit.graphfile import load
        from graphkit.registry import default_registry

        self.graph, self.values = load(graph_file, default_registry(), {}), values

    def input_values(self, node):
        return self.values.get(node)


def test_makeup_view_shows_the_whole_photo():
    """The makeup live view (studio) runs CosmeticShade on the whole photo, not a face crop,
    and its frame is the node's own output for the scaled map."""
    from conftest import ROOT
    from nodes.huang.studio_view import MakeupView

    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w]
    face = ((xx - 40) / 12.0) ** 2 + ((yy - 20) / 10.0) ** 2 < 1  # a small face off-centre
    t = np.stack([0.02 * face, 0.03 * (face & (xx > 40)), np.zeros((h, w))], -1).astype(np.float32)
    ins = {"albedo": Image(np.full((h, w, 3), 0.5, np.float32)), "thickness": Image(t), "skin": Mask(face.astype(np.float32))}
    view = MakeupView(_Studio(ROOT / "graphs" / "makeup.yaml", {"made_up": ins}), "made_up")
    assert f"whole {w}×{h} photo" in view.data()["note"]
    img = view.frame({"layer0": 2.0, "layer1": 0.5})
    p = view.params
    ref = run(CosmeticShade, {**ins, "thickness": Image(t * np.float32([2.0, 0.5, 1.0]))}, **{
        k: getattr(p, k) for k in ("cosmetics", "mm_per_pixel", "relight", "illuminant")})["image"].pixels
    assert img.pixels.shape == (h, w, 3) and np.array_equal(img.pixels, ref)
