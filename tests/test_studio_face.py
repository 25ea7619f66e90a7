"""The studio's WebGL2 face view (nodes/paris/studio_view.py + .js) in real headless Chromium
(Debian's chromium, SwiftShader WebGL2): the page draws Render's §5 model with the programs of
shaders/glsl/ preprocessed for GLSL ES 3.00, and its float read-back matches the numpy Render
for three light directions (shadows, detail texture, exposure + clamp) within the opengl
backend's own tolerance (RenderGL.tolerance: rtol 1e-3, atol 2e-3, at most 0.5 % of the values
outside; measured 0.03–0.05 %).  That needs gbuffer.frag's EXACT surface point: SwiftShader snaps
vertices to 1/16 px, and with GL's interpolated positions 6 % of the values were outside (the
detail texture's lookup moved by up to 0.03 texel).  The light is set through the view (its
frame() supplies the light's uniforms and shadow frame, as a drag on the sphere widget does)."""
from __future__ import annotations

import base64

import numpy as np
import pytest

from studio_support import Server, browser_page, need_browser, wait_for

GRAPH = """graphkit: 1
name: face_gl
nodes:
  scene: {type: FaceScene, params: {size: 96}}
  key: {type: MakeLight, params: {azimuth_deg: 20.0, elevation_deg: 10.0}}
  render:
    type: Render
    inputs: {mesh: scene.mesh, camera: scene.camera, material: scene.material, lights: [key.light],
             detail: scene.detail, texture_camera: scene.camera}
    params: {shadow_map_size: 256, exposure: 1.6, eye_highlights: "off"}
  save: {type: SaveImage, inputs: {image: render.image}, params: {path: r.exr}}
"""

DIRS = [(0.4, -0.5, -0.75), (-0.6, 0.3, -0.75), (0.05, 0.7, -0.7)]


@pytest.fixture(scope="module")
def pw():
    need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


def test_webgl_face_view_matches_numpy_render(pw, tmp_path):
    from graphkit import Light
    from graphkit.registry import default_registry
    from nodes.paris.render import Render

    import studionodes

    g = tmp_path / "g.yaml"
    g.write_text(GRAPH)
    s = Server(g, tmp_path)
    b, ctx = browser_page(pw, webgl=True)
    errors = []
    ctx.on("weberror", lambda e: errors.append(str(e.error)))
    try:
        page = ctx.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.goto(s.url)
        page.wait_for_selector("#dag g.node")
        wait_for(lambda: page.eval_on_selector("#run-status", "e => e.dataset.status") == "ok", 120, "the run")
        page.click('#dag g.node[data-node="render"]')
        page.wait_for_selector("#view-body canvas.face-gl", timeout=60000)
        wait_for(lambda: page.evaluate("() => !!document.querySelector('#view-body canvas.face-gl').gkFace"),
                 30, "the WebGL view")
        sc = studionodes.FaceScene().compute()
        ref = Render(Render.Params(shadow_map_size=256, exposure=1.6, eye_highlights="off"))
        tol = default_registry().backend_class("Render", "opengl").tolerance
        imgs = []
        for d in DIRS:
            page.evaluate("d => document.querySelector('#view-body canvas.face-gl').gkFace.setLight({direction: d})",
                          list(d))
            raw = page.evaluate("() => document.querySelector('#view-body canvas.face-gl').gkFace.readImage()")
            got = np.frombuffer(base64.b64decode(raw), np.float32).reshape(96, 96, 4)[..., :3]
            want = ref.compute(mesh=sc["mesh"], camera=sc["camera"], material=sc["material"],
                               lights=[Light(direction=d)], detail=sc["detail"],
                               texture_camera=sc["camera"])["image"].pixels
            bad = 1 - np.isclose(got, want, rtol=tol["rtol"], atol=tol["atol"]).mean()
            print(f"direction {d}: {bad:.3%} of values outside the opengl tolerance, "
                  f"max |diff| {np.abs(got - want).max():.2e}")
            assert bad <= tol["bad_fraction"], (d, bad)
            imgs.append(got)
        assert np.abs(imgs[0] - imgs[1]).max() > 0.2  # the light moved the shading
        assert not errors, errors
    finally:
        ctx.close()
        b.close()
        s.stop()
