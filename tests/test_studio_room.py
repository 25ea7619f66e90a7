"""The studio's room view (nodes/loscos/studio_view.py + .js) in real headless Chromium: a Relight
that inserts a virtual box shows the room at the photograph's resolution (the nodes' 40×32
example room) with a handle over the box; a mouse drag of the handle over the floor moves the box
through VirtualSession.move (the pixels change where it was and where it goes), and letting go
writes the box's new centre into the graph."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from studio_support import Server, browser_page, need_browser, open_view, wait_for

GRAPH = """graphkit: 1
name: room_view
nodes:
  scene: {type: LoadScene, params: {path: scene.yaml}}
  textures: {type: ProjectTextures, inputs: {scene: scene.scene, camera: scene.camera, photo: scene.photo},
             params: {resolution: 8}}
  radiosity: {type: RadiositySolve, inputs: {scene: scene.scene, projection: textures.projection},
              params: {eps_bf: 0.5, eps_bfv: 0.05, min_area: 0.02, max_level: 4}}
  refined: {type: TextureRefine, inputs: {scene: scene.scene, solution: radiosity.solution,
            projection: textures.projection}, params: {max_level: 4, min_area: 0.01, max_rounds: 1}}
  unoccluded: {type: Unocclude, inputs: {solution: refined.solution, projection: textures.projection,
               photo: scene.photo}}
  relit:
    type: Relight
    inputs: {solution: refined.solution, unoccluded: unoccluded.unoccluded, projection: textures.projection,
             photo: scene.photo, camera: scene.camera}
    params:
      virtual_boxes: [{name: crate, center: [0.4, -0.85, 0.2], size: [0.3, 0.3, 0.3], rotation_deg: 20,
                       reflectance: [0.8, 0.4, 0.1]}]
outputs: {relit: relit.image}
"""

PIXELS = """() => { const c = document.querySelector('#view-body canvas.room-img');
    return [c.width, c.height, Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data)]; }"""


@pytest.fixture(scope="module")
def pw():
    need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


def write_room(tmp_path):
    from nodes.io.images import encode_image
    from nodes.loscos.scene import example_doc, example_photo

    doc = {**example_doc(), "photo": "photo.exr"}
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(doc))
    (tmp_path / "photo.exr").write_bytes(encode_image(example_photo().pixels, ".exr", 32))
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH)
    return g


def test_drag_a_virtual_box_over_the_floor(pw, tmp_path):
    g = write_room(tmp_path)
    s = Server(g, tmp_path, plugins=None)
    b, ctx = browser_page(pw)
    errors = []
    try:
        page = open_view(ctx, s, "relit", errors)
        page.wait_for_function("() => +document.querySelector('#view-body canvas.room-img')?.dataset.frames > 0",
                               timeout=60000)
        W, H, before = page.evaluate(PIXELS)
        assert (W, H) == (40, 32)  # the photograph's resolution
        left, top, scale = page.eval_on_selector(
            "#view-body canvas.room-handles",
            "e => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.width / 40]; }")
        assert scale >= 2  # shown enlarged, pixel for pixel
        hx, hy = 26.0, 28.5  # on the crate (it covers x 23–29, y 26–32 of the 40×32 image)
        page.mouse.move(left + hx * scale, top + hy * scale)
        page.mouse.down()
        for k in range(1, 6):
            page.mouse.move(left + (hx - 2.0 * k) * scale, top + hy * scale)
            page.wait_for_timeout(50)
        wait_for(lambda: page.evaluate("() => +document.querySelector('#view-body canvas.room-img').dataset.frames") > 1,
                 60, "a frame of the drag")
        wait_for(lambda: "links re-evaluated" in page.inner_text("#view-body .room-info"), 30, "the drag's info")
        wait_for(lambda: page.evaluate("() => document.querySelector('#view-body canvas.room-img').dataset.busy") == "0",
                 60, "the frame of the drag's last position")
        _, _, after = page.evaluate(PIXELS)
        a = np.array(before, float).reshape(H, W, 4)[..., :3]
        c = np.array(after, float).reshape(H, W, 4)[..., :3]
        moved = np.abs(c - a).max(2) > 8
        assert moved[:, 24:30].sum() >= 6 and moved[:, 12:21].sum() >= 6, moved.astype(int)
        page.mouse.up()
        wait_for(lambda: s.api("/api/state")["nodes"] and next(
            n for n in s.api("/api/state")["nodes"] if n["name"] == "relit")["params"]["virtual_boxes"][0]["center"][0] < 0.35,
            60, "the new centre in the graph")
        assert not errors, errors
    finally:
        b.close()
        s.stop()
