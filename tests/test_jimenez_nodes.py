"""Jimenez 2010 nodes: the appearance rig (eqs. 4–6), SkinShade (§6), bad input, blush graph."""
from __future__ import annotations

import os

import numpy as np
import pytest

from conftest import ROOT, graphkit
from graphkit import BadInput, Image, Light, Mask
from graphkit.contract import compute_checked
from nodes.jimenez.histmatch import AppearanceRig, FlushTarget, LocalHistMatch
from nodes.jimenez.shade import SkinShade
from nodes.jimenez.skinlut import SkinColorLUT, lut_axes


def _maps(seed=0, shape=(48, 64)):
    rng = np.random.default_rng(seed)
    a = (rng.random(shape + (1,)) * 0.1).astype(np.float32)
    b = (rng.random(shape + (1,)) * 0.2 + 0.02).astype(np.float32)
    return Image(a), Image(b)


def test_rig_full_weight_on_a_basis_entry_reproduces_local_histogram_matching():
    hn, ht = _maps(1)
    lhm = LocalHistMatch(LocalHistMatch.Params(radius=6.0, stats_size=0)).compute(neutral=hn, target=ht)
    rig = AppearanceRig(AppearanceRig.Params(weights=[0.0, 1.0]))
    h = rig.compute(neutral=hn, neutral_mean=lhm["neutral_mean"], scales=[lhm["scale"]], biases=[lhm["bias"]])
    np.testing.assert_allclose(h.pixels, lhm["matched"].pixels, atol=1e-6)
    # w_0 = 1: the neutral map comes back unchanged; global scale multiplies
    rig0 = AppearanceRig(AppearanceRig.Params(weights=[1.0, 0.0], hemoglobin_scale=1.27))
    h0 = rig0.compute(neutral=hn, neutral_mean=lhm["neutral_mean"], scales=[lhm["scale"]], biases=[lhm["bias"]])
    np.testing.assert_allclose(h0.pixels, 1.27 * hn.pixels, atol=1e-6)


def test_rig_is_eq6_affine_blend():
    hn, _ = _maps(2)
    rng = np.random.default_rng(3)
    mu = Image(np.full((48, 64, 1), 0.05, np.float32))
    s = [Image((rng.random((48, 64, 1)) + 0.5).astype(np.float32)) for _ in range(2)]
    b = [Image((rng.random((48, 64, 1)) * 0.1).astype(np.float32)) for _ in range(2)]
    w = [0.2, 0.5, 0.3]
    h = AppearanceRig(AppearanceRig.Params(weights=w)).compute(neutral=hn, neutral_mean=mu, scales=s, biases=b)
    H0 = hn.pixels - 0.05
    ref = (w[0] * 0.05 + w[1] * b[0].pixels + w[2] * b[1].pixels) + H0 * (w[0] + w[1] * s[0].pixels + w[2] * s[1].pixels)
    np.testing.assert_allclose(h.pixels, np.maximum(ref, 0), atol=1e-6)


def test_stats_are_downsampled_and_upsampled_back():
    hn, ht = _maps(4, (200, 300))
    lhm = LocalHistMatch(LocalHistMatch.Params(radius=20.0, stats_size=64)).compute(neutral=hn, target=ht)
    assert lhm["scale"].pixels.shape == (43, 64, 1) and lhm["bias"].pixels.shape == (43, 64, 1)
    h = AppearanceRig(AppearanceRig.Params(weights=[0.0, 1.0])).compute(
        neutral=hn, neutral_mean=lhm["neutral_mean"], scales=[lhm["scale"]], biases=[lhm["bias"]])
    # low-frequency statistics survive 256²-style storage (§4.2): close to the full-size result
    err = np.abs(h.pixels - lhm["matched"].pixels)
    assert np.median(err) < 0.1 * ht.pixels.std()


def _refused(node, port: str, match: str, **inputs):
    """``node`` run as the engine runs it (declared constraints, then compute) refuses ``inputs``
    naming ``port``, with a message that matches ``match``."""
    with pytest.raises(BadInput, match=match) as e:
        compute_checked(node, **inputs)
    assert e.value.port == port, e.value


def test_bad_inputs_have_clear_messages():
    hn, ht = _maps(5)
    small = Image(np.zeros((10, 10, 1), np.float32))
    _refused(LocalHistMatch(), "target", "sizes differ", neutral=hn, target=small)
    _refused(LocalHistMatch(), "neutral", "negative", neutral=Image(hn.pixels - 1), target=ht)
    for port, bad, what in (("target", np.nan, "1 NaN and 0 Inf"), ("neutral", np.inf, "0 NaN and 1 Inf")):
        px = (ht if port == "target" else hn).pixels.copy()
        px[3, 4, 0] = bad
        _refused(LocalHistMatch(), port, f"holds {what} values", **{"neutral": hn, "target": ht, port: Image(px)})
    for r in (0.0, -3.0):
        _refused(LocalHistMatch(LocalHistMatch.Params(radius=r)), "radius", "radius must be > 0", neutral=hn, target=ht)
    lhm = LocalHistMatch(LocalHistMatch.Params(radius=4.0)).compute(neutral=hn, target=ht)
    args = dict(neutral=hn, neutral_mean=lhm["neutral_mean"], scales=[lhm["scale"]], biases=[lhm["bias"]])
    _refused(AppearanceRig(AppearanceRig.Params(weights=[0.5, 0.6])), "weights", "sum to one", **args)
    _refused(AppearanceRig(AppearanceRig.Params(weights=[1.0])), "weights", "2 weights|give 2", **args)
    _refused(AppearanceRig(AppearanceRig.Params(weights=[1.0, 0.0])), "neutral", "negative",
             **{**args, "neutral": Image(hn.pixels - 1)})
    lut = SkinColorLUT(SkinColorLUT.Params(size=8)).compute()["lut"]
    _refused(SkinShade(), "hemoglobin", "sizes differ", melanin=hn, hemoglobin=small, lut=lut, light=Light())
    _refused(SkinShade(), "melanin", "negative", melanin=Image(-hn.pixels), hemoglobin=ht, lut=lut, light=Light())
    _refused(LocalHistMatch(), "mask", "empty", neutral=hn, target=ht, mask=Mask(np.zeros((48, 64), np.float32)))
    _refused(FlushTarget(), "regions", "sizes differ: hemoglobin is 64×48×1, regions is 5×5",
             hemoglobin=hn, regions=Mask(np.ones((5, 5), np.float32)))


def test_skinshade_post_scatter_texturing_and_specular():
    from nodes.common.microfacet import kelemen_specular

    lut = SkinColorLUT(SkinColorLUT.Params(size=16)).compute()["lut"]
    cm, chd = lut_axes(16, 16)
    H, W = 32, 40
    # a checkerboard of two grid entries: post-scatter texturing must keep it sharp
    mel = np.where((np.indices((H, W)).sum(0) % 2) == 0, cm[3], cm[9]).astype(np.float32)[..., None]
    hem = np.full((H, W, 1), chd[7], np.float32)
    light = Light(direction=(0.0, 0.0, -1.0), color=(1.0, 0.9, 0.8), intensity=2.0, ambient=(0.05, 0.05, 0.05))
    out = SkinShade(SkinShade.Params(mm_per_pixel=0.1)).compute(melanin=Image(mel), hemoglobin=Image(hem), lut=lut, light=light)
    table = lut.pixels.astype(np.float64)
    alb = np.where(((np.indices((H, W)).sum(0) % 2) == 0)[..., None], table[7, 3], table[7, 9])
    np.testing.assert_allclose(out["albedo"].pixels, alb, atol=1e-6)
    irr = np.array([2.0, 1.8, 1.6]) + 0.05  # uniform light: scattering leaves it unchanged
    np.testing.assert_allclose(out["diffuse"].pixels, np.broadcast_to(irr, (H, W, 3)), rtol=1e-5)
    n = np.array([0.0, 0.0, -1.0])
    spec = kelemen_specular(n, n, n, 0.35, 0.18, 0.028)
    np.testing.assert_allclose(out["image"].pixels, alb * irr + spec * np.array([2.0, 1.8, 1.6]), rtol=1e-5)


def test_skinshade_pixel_terms_equal_a_float64_reference():
    """Without scattering, every output is pixel-local: the banded float32 path (bands of 48
    rows, the last one short; planes merged into 3 channels) equals a float64 evaluation of
    albedo·(light·max(N·L, 0) + ambient) + specular·light, with unnormalised normals."""
    from nodes.common.microfacet import kelemen_specular
    from nodes.jimenez.skinlut import lut_lookup

    H, W = 97, 61
    rng = np.random.default_rng(5)
    lut = SkinColorLUT(SkinColorLUT.Params(size=16)).compute()["lut"]
    mel = (rng.random((H, W, 1)) * 0.3).astype(np.float32)
    hem = (rng.random((H, W, 1)) * 0.2).astype(np.float32)
    nrm = (rng.normal(size=(H, W, 3)) * [0.5, 0.5, 1] + [0, 0, -1.5]).astype(np.float32)
    light = Light(direction=(0.5, -0.2, -1.0), color=(1.0, 0.8, 0.6), intensity=1.5, ambient=(0.02, 0.03, 0.04))
    out = SkinShade(SkinShade.Params(scatter=False)).compute(
        melanin=Image(mel), hemoglobin=Image(hem), lut=lut, light=light, normals=Image(nrm))
    n = nrm.astype(np.float64)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    ldir = np.array(light.direction) / np.linalg.norm(light.direction)
    col = np.array(light.color) * light.intensity
    irr = np.maximum(n @ ldir, 0)[..., None] * col + np.array(light.ambient)
    spec = kelemen_specular(n, ldir, np.array([0, 0, -1.0]), 0.35, 0.18, 0.028)
    alb = lut_lookup(lut.pixels, mel[..., 0], hem[..., 0]).astype(np.float64)
    np.testing.assert_allclose(out["albedo"].pixels, alb, rtol=0, atol=1e-7)
    np.testing.assert_allclose(out["diffuse"].pixels, irr, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(out["specular"].pixels[..., 0], spec, rtol=2e-5, atol=1e-8)
    np.testing.assert_allclose(out["image"].pixels, alb * irr + spec[..., None] * col, rtol=1e-5, atol=1e-7)


def test_skinshade_scatters_a_shadow_edge_red_furthest():
    lut = SkinColorLUT(SkinColorLUT.Params(size=8)).compute()["lut"]
    H, W = 16, 80
    nrm = np.zeros((H, W, 3), np.float32)
    nrm[..., 2] = -1.0
    nrm[:, W // 2:, 0] = 1.0  # right half faces away from the light: shadow edge
    nrm[:, W // 2:, 2] = 0.0
    z = Image(np.zeros((H, W, 1), np.float32))
    out = SkinShade(SkinShade.Params(mm_per_pixel=0.1)).compute(
        melanin=z, hemoglobin=z, lut=lut, light=Light(direction=(0.0, 0.0, -1.0)), normals=Image(nrm))
    d = out["diffuse"].pixels[H // 2]
    bleed = d[W // 2 + 2]  # light scattered into the shadow
    assert bleed[0] > bleed[1] > bleed[2] > 0


def _need_facemesh():
    from graphkit.registry import default_registry

    if "FaceMesh" not in default_registry().nodes:
        pytest.skip(reason="FaceMesh (plugins/graphkit-mediapipe + mediapipe 0.10.14) is not installed; `make` installs it")


def test_blush_graph_runs(tmp_path):
    _need_facemesh()
    import OpenImageIO as oiio

    env = dict(os.environ)
    env.pop("GRAPHKIT_TRACEBACK", None)
    out = tmp_path / "out"
    r = graphkit("run", ROOT / "graphs" / "blush.yaml", "--out", out, "--cache", tmp_path / "cache", "-q",
                 env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    from graphkit import Context
    from nodes.io.images import LoadImage

    photo = LoadImage(LoadImage.Params(path="builtin:astronaut"), Context()).compute().pixels
    w0 = np.asarray(oiio.ImageBuf(str(out / "blush" / "w_flush_0.exr")).get_pixels(oiio.FLOAT))
    w1 = np.asarray(oiio.ImageBuf(str(out / "blush" / "w_flush_100.exr")).get_pixels(oiio.FLOAT))
    np.testing.assert_allclose(w0, photo, atol=2e-3 * (1 + photo.max()))  # w = [1, 0]: the photo (half-float EXR)
    changed = np.abs(w1 - photo).max(-1) > 0.01
    ys, xs = np.nonzero(changed)
    assert 0.001 < changed.mean() < 0.2 and 100 < ys.mean() < 300 and 150 < xs.mean() < 330  # the face
    # more blood: red rises relative to green where it changed
    ratio = (w1[changed] + 1e-4) / (photo[changed] + 1e-4)
    assert np.median(ratio[:, 0] / ratio[:, 1]) > 1.0
    assert (out / "blush" / "contact_sheet.png").is_file()
    bad = graphkit("run", ROOT / "graphs" / "blush.yaml", "--out", tmp_path / "o2", "--cache", tmp_path / "cache",
                   "-q", "--set", "weights=[0.5, 0.6]", env=env, timeout=300)
    assert bad.returncode == 2 and "sum to one" in bad.stderr


def test_examples_run():
    for cls in (LocalHistMatch, AppearanceRig, SkinShade):
        for params, inputs in cls.examples():
            cls(cls.Params(**params)).compute(**inputs)


def test_matching_a_map_to_itself_is_the_identity():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=12, deadline=None, derandomize=True)
    @given(st.integers(8, 40), st.integers(8, 40), st.floats(0.5, 60.0), st.integers(0, 2**31 - 1))
    def prop(h, w, r, seed):
        a = Image((np.random.default_rng(seed).random((h, w, 1)) * 0.3).astype(np.float32))
        out = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=0)).compute(neutral=a, target=a)
        np.testing.assert_allclose(out["matched"].pixels, a.pixels, atol=2e-6)
        np.testing.assert_allclose(out["scale"].pixels, 1.0, atol=1e-3)

    prop()


def test_skinshade_camera_footprint_equals_explicit_mm_per_pixel():
    from graphkit import Camera

    lut = SkinColorLUT(SkinColorLUT.Params(size=8)).compute()["lut"]
    rng = np.random.default_rng(9)
    H, W = 20, 30
    mel = Image((rng.random((H, W, 1)) * 0.05).astype(np.float32))
    hem = Image((rng.random((H, W, 1)) * 0.05).astype(np.float32))
    nrm = rng.normal(size=(H, W, 3)).astype(np.float32)
    nrm[..., 2] = -np.abs(nrm[..., 2]) - 1
    depth = Image(np.full((H, W, 1), 600.0, np.float32))
    cam = Camera(width=W, height=H, fx=1200.0, fy=1200.0, cx=W / 2, cy=H / 2)
    light = Light(direction=(0.2, -0.1, -1.0))
    a = SkinShade().compute(melanin=mel, hemoglobin=hem, lut=lut, light=light, normals=Image(nrm), depth=depth, camera=cam)
    b = SkinShade(SkinShade.Params(mm_per_pixel=0.5)).compute(melanin=mel, hemoglobin=hem, lut=lut, light=light,
                                                              normals=Image(nrm), depth=depth)
    np.testing.assert_allclose(a["image"].pixels, b["image"].pixels, atol=1e-6)


@pytest.mark.parametrize("case", [0, 1, 2])
def test_skinshade_scatters_n_dot_l_as_a_hook_scatters_the_irradiance(case):
    """With the reference SSS SkinShade scatters N·L once per Gaussian and forms
    diffuse = light · sss(N·L) + ambient (the scatter is linear, the profile's weights sum to
    one per channel); a backend's hook is given the irradiance E itself.  Both give the same
    diffuse and image to float rounding (flat; mask and depth gradient; camera footprint)."""
    from nodes.common import sss

    class Hooked(SkinShade):
        sss_blur = staticmethod(lambda *a, **k: sss.sss_blur(*a, **k))

    params, inputs = SkinShade.examples()[case]
    light = inputs["light"]
    inputs = {**inputs, "light": Light(direction=light.direction, color=(1.0, 0.8, 0.6), intensity=1.5,
                                       ambient=(0.05, 0.04, 0.03))}
    p = SkinShade.Params.model_validate(params)
    ref, got = Hooked(p).compute(**inputs), SkinShade(p).compute(**inputs)
    if "normals" in inputs:  # the light varies over the skin: something is scattered
        assert float(np.ptp(got["diffuse"].pixels[..., 0])) > 0.05
    for port in ("diffuse", "image"):
        np.testing.assert_allclose(got[port].pixels, ref[port].pixels, rtol=1e-6, atol=1e-7)


def _gather_sss(img, mpp, depth=None, mask=None):
    """Reference screen-space SSS with the exact per-pixel gather (nodes.common.sss._blur_axis,
    itself checked against scipy in tests/test_sss.py): each pixel's kernel is the Gaussian of
    its own σ, y then x, per Gaussian of the d'Eon profile."""
    from nodes.common.sss import SKIN_PROFILE, _blur_axis, _pixel_step_mm

    valid = None if mask is None else (mask > 0.5).astype(np.float64)
    step_x, step_y = _pixel_step_mm(np.asarray(mpp, np.float64), depth, img.shape[:2])
    out = np.zeros(img.shape)
    for var, rgb in SKIN_PROFILE:
        sd = np.sqrt(var)
        b = _blur_axis(img.astype(np.float32), np.broadcast_to(sd / step_y, img.shape[:2]), 0, valid)
        b = _blur_axis(b, np.broadcast_to(sd / step_x, img.shape[:2]), 1, valid)
        out += b * np.asarray(rgb)
    return out if valid is None else np.where(valid[..., None] > 0, out, img)


def _sphere(H, W, r_mm, mm_per_px_xy=1.0):
    """Depth (mm) of a sphere of radius r_mm seen from 500 mm, and its mask away from the rim."""
    yy, xx = np.mgrid[0:H, 0:W]
    z2 = r_mm ** 2 - ((xx - W / 2) * mm_per_px_xy) ** 2 - ((yy - H / 2) * mm_per_px_xy) ** 2
    return 500.0 - np.sqrt(np.maximum(z2, 1.0)), (z2 > 100).astype(np.float64)


def test_sss_depth_gradient_levels_against_the_per_pixel_gather():
    """sss_blur evaluates a per-pixel kernel width (depth gradient) as uniform cv2 blurs at σ
    levels a factor 2 apart (nodes.common.sss.LEVEL_RATIO), interpolated linearly in σ; the
    exact per-pixel gather is the reference (the oracle, at a small size).  A sphere: σ falls
    from its centre to 0 at the silhouette (σ < IDENTITY_SIGMA ≈ 0.17 px and the level ends are exact, the rest
    interpolated).  Tolerances, stated in nodes/jimenez/README.md: white noise with a bright
    square (the worst case: every pixel differs from its neighbours; values 0…6) max ≤ 1.5 % of
    the range (measured 1.1 %, at the square's edges: ~1 % of a step, as for the analytic step
    in tests/test_sss.py), mean ≤ 0.05 % (measured 0.03 %); the astronaut as a linear irradiance
    (values 0…1) max ≤ 1.5e-2, PSNR ≥ 55 dB (measured ≤ 1.13e-2, 60.2–64.4 dB)."""
    from skimage import data, transform

    from nodes.common.sss import sss_blur

    rng = np.random.default_rng(10)
    H, W = 90, 120
    noise = rng.random((H, W, 3)).astype(np.float32)
    noise[40:48, 55:63] = 6.0
    depth, mask = _sphere(H, W, 42.0)
    for m in (None, mask):
        for mpp in (0.3, 0.12):
            err = np.abs(sss_blur(noise, mpp, depth, mask=m) - _gather_sss(noise, mpp, depth, m))
            print(f"levels vs gather, noise on a sphere, mpp {mpp}, mask {m is not None}: max {err.max():.2e}, "
                  f"mean {err.mean():.2e} (values 0…6)")
            assert err.max() <= 0.09 and err.mean() <= 3e-3
    photo = (transform.resize(data.astronaut(), (96, 128), anti_aliasing=True) ** 2.2).astype(np.float32)
    depth, mask = _sphere(96, 128, 46.0)
    for m in (None, mask):
        for mpp in (0.3, 0.12):
            err = np.abs(sss_blur(photo, mpp, depth, mask=m) - _gather_sss(photo, mpp, depth, m))
            psnr = 10 * np.log10(1.0 / np.mean(err ** 2))
            print(f"levels vs gather, astronaut on a sphere, mpp {mpp}, mask {m is not None}: max {err.max():.2e}, "
                  f"PSNR {psnr:.1f} dB")
            assert err.max() <= 1.5e-2 and psnr >= 55.0
    # two pixel footprints (σ takes two values per Gaussian): exact
    mpp = np.where(np.arange(W)[None, :] < 60, 0.2, 0.45) * np.ones((H, 1))
    np.testing.assert_allclose(sss_blur(noise, mpp), _gather_sss(noise, mpp), atol=1e-5)


def test_blush_view_shows_the_whole_photo():
    """The blush live view (studio) runs the rig and ApplyHemoglobin on the whole photo, not a
    crop around the skin: its frame is ApplyHemoglobin's output for the rig at the sliders."""
    from graphkit.graphfile import load
    from graphkit.registry import default_registry
    from nodes.jimenez.chromophores import ApplyHemoglobin
    from nodes.jimenez.studio_view import BlushView

    h, w = 40, 56
    rng = np.random.default_rng(5)
    skin = np.zeros((h, w), np.float32)
    skin[10:25, 30:50] = 1  # a small skin patch off-centre
    hb = Image(rng.random((h, w, 1), dtype=np.float32) * 0.05)
    rig_in = {"neutral": hb, "neutral_mean": Image(np.full((5, 7, 1), 0.02, np.float32)),
              "scales": [Image(np.full((5, 7, 1), 1.5, np.float32))], "biases": [Image(np.full((5, 7, 1), 0.04, np.float32))]}
    ap_in = {"image": Image(rng.random((h, w, 3), dtype=np.float32)), "pigments": np.array([[1.0, 2.0, 3.0], [0.5, 2.0, 1.5]]),
             "hemoglobin": hb, "new_hemoglobin": hb, "mask": Mask(skin)}

    class Studio:
        graph = load(ROOT / "graphs" / "blush.yaml", default_registry(), {})

        def input_values(self, node):
            return {"rig": rig_in, "recolor": ap_in}.get(node)

    view = BlushView(Studio(), "rig")
    assert f"whole {w}×{h} photo" in view.data()["note"]
    img = view.frame({"w1": 0.7, "hemoglobin_scale": 1.2})
    new_h = compute_checked(AppearanceRig(AppearanceRig.Params(weights=[0.3, 0.7], hemoglobin_scale=1.2)), **rig_in)
    ref = compute_checked(ApplyHemoglobin(ApplyHemoglobin.Params()), **{**ap_in, "new_hemoglobin": new_h})
    assert img.pixels.shape == (h, w, 3) and np.array_equal(img.pixels, ref.pixels)
