"""Issue 26, the portrait path: its bad input through the CLI: a photo whose face is not found, and
a mesh that does not overlap the photo (beside it, or only its corner) exit 2 with one message
naming the node, the port and what to do, no traceback, nothing in the output folder and no
entry in the cache for the refused node or anything after it.  And the studio's live view of
CompositeFace (a slider moves the light, the whole photo relit) on the same small capture."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "nodes" / "paris" / "data" / "sample_capture"

PORTRAIT = """graphkit: 1
name: portrait_bad_input
nodes:
  photo: {type: LoadImage, params: {path: photo.exr}}
  mesh: {type: LoadMesh, params: {path: mesh.ply}}
  moved: {type: LoadMesh, params: {path: moved.ply}}
  camera: {type: LoadCameraJson, params: {path: camera.json}}
  skin: {type: MeshMask, inputs: {mesh: mesh.mesh, camera: camera.camera}}
  flash: {type: MakeLight, inputs: {camera: camera.camera}}
  fit: {type: FitSkinPhong, inputs: {image: photo.image, skin: skin.mask, mesh: mesh.mesh, camera: camera.camera, light: flash.light},
        params: {starts: 1, shininess_search: false}}
  lamp: {type: MakeLight, inputs: {camera: camera.camera}, params: {azimuth_deg: 30.0}}
  relit: {type: Render, inputs: {mesh: moved.mesh, camera: camera.camera, material: fit.material, lights: [lamp.light]}}
  portrait: {type: CompositeFace, inputs: {photo: photo.image, relit: relit.image, coverage: relit.coverage}}
  save: {type: SaveImage, inputs: {image: portrait.image}, params: {path: portrait.exr}}
outputs: {portrait: save.file}
"""


def _run(args, cwd):
    env = dict(os.environ, GRAPHKIT_CACHE=str(Path(cwd) / "cache"))
    return subprocess.run([sys.executable, "-m", "graphkit", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env=env)


def _refused(r, tmp_path, node: str, port: str, *words: str):
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr
    assert f"node '{node}'" in r.stderr and f"port '{port}'" in r.stderr, r.stderr
    for w in words:
        assert w in r.stderr, (w, r.stderr)
    out = tmp_path / "out"
    assert not out.exists() or not any(out.iterdir()), list(out.iterdir())
    ls = _run(["cache", "ls"], tmp_path)
    assert ls.returncode == 0, ls.stderr
    return ls.stdout


def test_a_photo_without_a_face(tmp_path):
    from graphkit.registry import default_registry

    if "FaceMesh" not in default_registry().node_names():
        pytest.skip(reason="needs the graphkit-mediapipe plugin (FaceMesh)")
    import cv2

    rng = np.random.default_rng(0)
    grey = np.clip(0.5 + 0.1 * rng.standard_normal((240, 320, 3)), 0, 1)
    cv2.imwrite(str(tmp_path / "wall.png"), np.round(grey * 255).astype(np.uint8))
    text = (ROOT / "graphs" / "phone_relight.yaml").read_text().replace(
        'path: "builtin:astronaut"', f'path: "{tmp_path / "wall.png"}"')
    assert str(tmp_path / "wall.png") in text
    (tmp_path / "g.yaml").write_text(text)
    r = _run(["run", "g.yaml", "--out", "out"], tmp_path)
    listed = _refused(r, tmp_path, "face", "image", "no face found", "use a photo with one frontal")
    assert "LoadPhoto" in listed and "FaceMesh" not in listed and "CompositeFace" not in listed, listed


@pytest.mark.parametrize("case", ["beside", "corner"])
def test_a_mesh_that_does_not_overlap_the_photo(tmp_path, case):
    import trimesh

    for f in DATA.iterdir():
        shutil.copy(f, tmp_path / f.name)
    m = trimesh.load(tmp_path / "mesh.ply", process=False)
    V = np.asarray(m.vertices)
    xy = V[:, :2] * 1185.185 / V[:, 2:3] + 64.0  # the sample camera: f 1185 px, centre 64
    if case == "beside":  # the projection misses the 128² photo: Render refuses
        m.apply_translation([3000.0, 0, 0])
        expect = ("relit", "mesh", "the mesh is beside the camera", "wrong pose, units or image size")
    else:  # only a corner of the photo (39 pixels): CompositeFace refuses
        dx = (116.0 - xy[:, 0].min()) * V[:, 2].min() / 1185.185
        dy = (116.0 - xy[:, 1].min()) * V[:, 2].min() / 1185.185
        m.apply_translation([dx, dy, 0.0])
        expect = ("portrait", "coverage", "the mesh does not overlap the photo", "check the mesh and the camera")
    m.export(tmp_path / "moved.ply")
    (tmp_path / "g.yaml").write_text(PORTRAIT)
    r = _run(["run", "g.yaml", "--out", "out"], tmp_path)
    listed = _refused(r, tmp_path, *expect)
    assert "LoadMesh" in listed and "CompositeFace" not in listed and "SaveImage" not in listed, listed


def _composite_view(tmp_path):
    """CompositeView on PORTRAIT's `portrait`, after a run: (the view, the run, the studio)."""
    from graphkit.api import run_graph
    from nodes.paris.studio_view import CompositeView

    for f in DATA.iterdir():
        shutil.copy(f, tmp_path / f.name)
    shutil.copy(tmp_path / "mesh.ply", tmp_path / "moved.ply")
    (tmp_path / "g.yaml").write_text(PORTRAIT)
    run = run_graph(tmp_path / "g.yaml", cache=tmp_path / "cache", outputs=["portrait"])

    class Studio:  # what a live view reads of the studio
        graph = run.graph

        @staticmethod
        def input_values(node):
            return run.graph.nodes[node].map_inputs(lambda s, p: run.value(f"{s}.{p}"))

        class doc:  # the graph file as written
            @staticmethod
            def data():
                import yaml

                return yaml.safe_load(PORTRAIT)

    return CompositeView(Studio, "portrait"), run, Studio


def test_composite_live_view_moves_the_light(tmp_path):
    """CompositeView: a slider move re-renders the Render feeding `relit` with its first light at
    the new angles and composites it (the frame is Render + CompositeFace on that light); letting
    go sets that MakeLight's angles; a `relit` not from a Render is refused naming the port."""
    from graphkit import BadInput
    from nodes.paris.composite import CompositeFace
    from nodes.paris.render import MakeLight, Render

    view, run, Studio = _composite_view(tmp_path)
    assert [s["value"] for s in view.data()["sliders"]] == [30.0, 0.0]
    got = view.frame({"azimuth": -20.0, "elevation": 15.0}).pixels
    given = Studio.input_values("relit")
    lamp = MakeLight(MakeLight.Params(azimuth_deg=-20.0, elevation_deg=15.0)).compute(camera=given["camera"])
    r = Render(run.graph.nodes["relit"].params).compute(**{**given, "lights": [lamp]})
    want = CompositeFace(CompositeFace.Params()).compute(photo=run.value("photo.image"), relit=r["image"],
                                                         coverage=r["coverage"])["image"].pixels
    assert np.array_equal(got, want) and not np.array_equal(got, run.value("portrait.image").pixels)
    assert view.commit({"azimuth": -20.0, "elevation": 15.0}) == [
        {"node": "lamp", "param": "azimuth_deg", "value": -20.0},
        {"node": "lamp", "param": "elevation_deg", "value": 15.0}]
    run.graph.nodes["portrait"].inputs["relit"] = ("photo", "image")
    with pytest.raises(BadInput, match="relit"):
        view.frame({"azimuth": 0.0})


def test_composite_live_view_previews_a_large_photo_reduced(tmp_path, monkeypatch):
    """A photo over CompositeView.PREVIEW_MAX_PX (a phone's 12 megapixels) is previewed reduced by
    a whole factor — the face rendered through the camera reduced alike, the photo's k×k blocks
    averaged — so that a slider keeps up; the frame is Render + CompositeFace at that size, and
    looks like the full-size result reduced (over 30 dB), not like the light before."""
    from nodes.paris.composite import CompositeFace
    from nodes.paris.render import MakeLight, Render
    from graphkit import Image
    from nodes.paris.studio_view import CompositeView, reduce_image, reduced_camera

    view, run, Studio = _composite_view(tmp_path)
    photo = run.value("photo.image").pixels
    h, w = photo.shape[:2]
    monkeypatch.setattr(CompositeView, "PREVIEW_MAX_PX", (h // 2) * (w // 2))
    assert "reduced 2×" in view.data()["note"]
    got = view.frame({"azimuth": -20.0, "elevation": 15.0}).pixels
    assert got.shape[:2] == (h // 2, w // 2)
    given = Studio.input_values("relit")
    lamp = MakeLight(MakeLight.Params(azimuth_deg=-20.0, elevation_deg=15.0)).compute(camera=given["camera"])
    small = reduced_camera(given["camera"], 2)
    assert (small.width, small.height) == (w // 2, h // 2) and small.cx == pytest.approx(given["camera"].cx / 2)
    r = Render(run.graph.nodes["relit"].params).compute(**{**given, "camera": small, "lights": [lamp]})
    want = CompositeFace(CompositeFace.Params()).compute(photo=Image(reduce_image(photo, 2)), relit=r["image"],
                                                         coverage=r["coverage"])["image"].pixels
    assert np.array_equal(got, want)
    full = Render(run.graph.nodes["relit"].params).compute(**{**given, "lights": [lamp]})
    whole = CompositeFace(CompositeFace.Params()).compute(photo=run.value("photo.image"), relit=full["image"],
                                                          coverage=full["coverage"])["image"].pixels
    ref = reduce_image(whole, 2)

    def psnr(a, b):
        return 10 * np.log10(1.0 / np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2))

    before = reduce_image(run.value("portrait.image").pixels, 2)
    assert psnr(got, ref) > 30 and psnr(got, ref) > psnr(before, ref) + 6, (psnr(got, ref), psnr(before, ref))
