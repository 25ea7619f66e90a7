"""The studio's WebGL2 face view (nodes/paris/studio_view.py + .js) in real headless Chromium
(Debian's chromium, SwiftShader WebGL2): the page draws Render's §5 model with the programs of
shaders/glsl/ preprocessed for GLSL ES 3.00, and its float read-back matches the numpy Render
for three light directions (shadows, detail texture, exposure + clamp) within the opengl
backend's own tolerance (RenderGL.tolerance: rtol 1e-3, atol 2e-3, at most 0.5 % of the values
outside; measured 0.03–0.05 %), with and without the eye highlights (whose 8–10 pixels must
match on their own: a half-strength highlight puts 73 % of them outside).  That needs gbuffer.frag's EXACT surface point: SwiftShader snaps
vertices to 1/16 px, and with GL's interpolated positions 6 % of the values were outside (the
detail texture's lookup moved by up to 0.03 texel).  The light is set through the view (its
frame() supplies the light's uniforms and shadow frame, as a drag on the sphere widget does)."""
from __future__ import annotations

import base64

import numpy as np
import pytest

from studio_support import Server, browser_page, need_browser, open_view, wait_for

GRAPH = """graphkit: 1
name: face_gl
nodes:
  scene: {type: FaceScene, params: {size: 96}}
  key: {type: MakeLight, params: {azimuth_deg: 20.0, elevation_deg: 10.0}}
  render:
    type: Render
    inputs: {mesh: scene.mesh, camera: scene.camera, material: scene.material, lights: [key.light],
             detail: scene.detail, texture_camera: scene.camera}
    params: PARAMS
  save: {type: SaveImage, inputs: {image: render.image}, params: {path: r.exr}}
"""

DIRS = [(0.4, -0.5, -0.75), (-0.6, 0.3, -0.75), (0.05, 0.7, -0.7)]
#: Render's params per case: the §5 model without, and with, the eye highlights (the eyes'
#: own program over their screen box; two cornea spheres just in front of the "head")
CASES = {
    "shadows_detail_exposure": ({"shadow_map_size": 256, "exposure": 1.6, "eye_highlights": "off"}, DIRS),
    "eye_highlights": ({"shadow_map_size": 256, "exposure": 1.3, "eye_highlights": "on",
                        "eyes": [[-0.25, -0.2, 3.7], [0.25, -0.2, 3.7]], "mm_per_unit": 30.0,
                        "eye_shininess": 60.0}, [(0.1, -0.2, -1.0), (-0.4, 0.3, -0.8)]),
}


@pytest.fixture(scope="module")
def pw():
    need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


@pytest.mark.parametrize("case", CASES)
def test_webgl_face_view_matches_numpy_render(pw, tmp_path, case):
    import json
    from graphkit import Light
    from graphkit.registry import default_registry
    from nodes.paris.render import Render

    import studionodes

    g = tmp_path / "g.yaml"
    params, dirs = CASES[case]
    g.write_text(GRAPH.replace("PARAMS", json.dumps(params)))
    s = Server(g, tmp_path)
    b, ctx = browser_page(pw, webgl=True)
    errors = []
    ctx.on("weberror", lambda e: errors.append(str(e.error)))
    try:
        page = open_view(ctx, s, "render", errors)
        page.wait_for_selector("#view-body canvas.face-gl", timeout=60000)
        wait_for(lambda: page.evaluate("() => !!document.querySelector('#view-body canvas.face-gl').gkFace"),
                 30, "the WebGL view")
        sc = studionodes.FaceScene().compute()
        ref = Render(Render.Params(**params))
        tol = default_registry().backend_class("Render", "opengl").tolerance
        imgs = []
        for d in dirs:
            page.evaluate("d => document.querySelector('#view-body canvas.face-gl').gkFace.setLight({direction: d})",
                          list(d))
            raw = page.evaluate("() => document.querySelector('#view-body canvas.face-gl').gkFace.readImage()")
            got = np.frombuffer(base64.b64decode(raw), np.float32).reshape(96, 96, 4)[..., :3]
            inputs = dict(mesh=sc["mesh"], camera=sc["camera"], material=sc["material"],
                          lights=[Light(direction=d)], detail=sc["detail"], texture_camera=sc["camera"])
            want = ref.compute(**inputs)["image"].pixels
            eye = None
            if params["eye_highlights"] == "on":  # the case is about the eyes: they must show
                plain = Render(Render.Params(**{**params, "eye_highlights": "off"})).compute(**inputs)
                eye = np.abs(want - plain["image"].pixels).max(-1) > 0.05
                assert eye.sum() >= 5
            bad = 1 - np.isclose(got, want, rtol=tol["rtol"], atol=tol["atol"]).mean()
            print(f"direction {d}: {bad:.3%} of values outside the opengl tolerance, "
                  f"max |diff| {np.abs(got - want).max():.2e}")
            assert bad <= tol["bad_fraction"], (d, bad)
            if eye is not None:  # the few highlight pixels must match too, not just the whole image
                bad_eye = 1 - np.isclose(got[eye], want[eye], rtol=tol["rtol"], atol=tol["atol"]).mean()
                print(f"  eye highlights: {int(eye.sum())} pixels, {bad_eye:.1%} of their values outside")
                assert bad_eye <= 0.1, (d, bad_eye)
            imgs.append(got)
            # the general programs (point-light code in) give the same image as the DIRECTIONAL
            # ones the view draws with a directional light
            gen = np.frombuffer(base64.b64decode(page.evaluate(
                "() => document.querySelector('#view-body canvas.face-gl').gkFace.readImage(true)")),
                np.float32).reshape(96, 96, 4)[..., :3]
            assert np.abs(gen - got).max() <= 1e-6, np.abs(gen - got).max()
            # the PCF as 4 depth-compare samples (shade.frag SM_BILINEAR, what the view draws
            # with) counts the same lit taps as the 9 texel fetches: the very same bytes
            taps = base64.b64decode(page.evaluate(
                "() => document.querySelector('#view-body canvas.face-gl').gkFace.readImage('taps')"))
            gen_raw = base64.b64decode(page.evaluate(
                "() => document.querySelector('#view-body canvas.face-gl').gkFace.readImage(true)"))
            assert taps == gen_raw, np.abs(np.frombuffer(taps, np.float32) - np.frombuffer(gen_raw, np.float32)).max()
        assert np.abs(imgs[0] - imgs[1]).max() > 0.2  # the light moved the shading
        # a frame draws the lighting pass straight onto the canvas (shade.frag DISPLAY): the
        # same pixels as the float image through display.frag (sRGB, flipped), to 1/255
        one, two = (np.frombuffer(base64.b64decode(page.evaluate(
            f"() => document.querySelector('#view-body canvas.face-gl').gkFace.readCanvas({t})")),
            np.uint8).reshape(96, 96, 4).astype(int) for t in ("false", "true"))
        assert np.abs(one - two).max() <= 1 and np.abs(two[..., :3] - two[0, 0, :3]).max() > 50, \
            np.abs(one - two).max()
        assert not errors, errors
    finally:
        ctx.close()
        b.close()
        s.stop()


def test_face_view_light_frame_in_page_equals_host(pw, tmp_path):
    """A drag's light frame is computed in the page (studio_view.js lightFrame: the light's
    uniforms and its shadow map's frame, float64) with FaceView.frame's formulas: the two agree
    to float64 rounding for directions all round the face (grazing, from behind, near the
    camera's y axis, where _look_frame changes its up vector) with colours and intensities; a
    value the page does not take gives null there and the host's error."""
    import json

    g = tmp_path / "g.yaml"
    g.write_text(GRAPH.replace("PARAMS", json.dumps({"shadow_map_size": 256, "eye_highlights": "off"})))
    s = Server(g, tmp_path)
    b, ctx = browser_page(pw, webgl=True)
    face = "document.querySelector('#view-body canvas.face-gl').gkFace"
    try:
        page = open_view(ctx, s, "render", [])
        page.wait_for_selector("#view-body canvas.face-gl", timeout=60000)
        wait_for(lambda: page.evaluate(f"() => !!{face}"), 30, "the WebGL view")
        cases = [{"direction": [0.4, -0.5, -0.75]}, {"direction": [-0.6, 0.3, -0.75], "intensity": 2.5},
                 {"direction": [1.0, 0.0, 0.0], "color": [0.2, 0.5, 1.0]}, {"direction": [0.0, 0.0, 1.0]},
                 {"direction": [0.01, 0.999, -0.02], "intensity": 0.0}, {"direction": [0.05, -3.0, 0.1]},
                 {"direction": [3.0, 4.0, -12.0], "intensity": 1.7, "color": [1.0, 0.9, 0.8]}]
        for v in cases:
            mine = page.evaluate(f"v => {face}.lightFrame(v)", v)
            host = page.evaluate(f"v => {face}.hostFrame(v)", v)
            assert isinstance(host, dict) and mine is not None, (v, host)
            assert mine.keys() == host.keys(), (mine.keys(), host.keys())
            assert len(mine["lights"]) == len(host["lights"]) and len(mine["shadow"]) == len(host["shadow"])
            assert mine["shadow_map_size"] == host["shadow_map_size"]
            for a, h in zip(mine["lights"] + mine["shadow"], host["lights"] + host["shadow"]):
                assert a.keys() == h.keys(), (a.keys(), h.keys())
                for k in a:
                    if h[k] is None or isinstance(h[k], (int, str)):
                        assert a[k] == h[k], (v, k, a[k], h[k])
                        continue
                    x, y = np.asarray(a[k], np.float64), np.asarray(h[k], np.float64)
                    assert x.shape == y.shape and np.allclose(x, y, rtol=1e-12, atol=1e-12 * max(np.abs(y).max(), 1)), \
                        (v, k, x, y)
        for bad in ({"direction": [0.0, 0.0, 0.0]}, {"direction": [1.0, "x", 0.0]}, {"intensity": -1.0}):
            assert page.evaluate(f"v => {face}.lightFrame(v)", bad) is None, bad
        # (the host's own refusal, as a drag with such a value would show it)
        assert "not a direction" in page.evaluate(f"v => {face}.hostFrame(v)", {"direction": [0.0, 0.0, 0.0]})
    finally:
        ctx.close()
        b.close()
        s.stop()
