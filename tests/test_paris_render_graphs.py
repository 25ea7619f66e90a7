"""graphs/face_capture.yaml end to end through the CLI, and bad inputs through the CLI: exit 2,
a message naming the node and the port, no traceback."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
GRAPHKIT = [sys.executable, "-m", "graphkit"]
DATA = ROOT / "nodes" / "paris" / "data" / "sample_capture"


def _run(args, cwd, timeout=240):
    env = dict(os.environ)
    env["GRAPHKIT_CACHE"] = str(Path(cwd) / "cache")
    return subprocess.run(GRAPHKIT + args, cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_face_capture_graph_runs(tmp_path):
    from graphkit.registry import default_registry

    names = default_registry().node_names()
    missing = [n for n in ("ProbeLight", "SkinSegment", "ShininessFromSaturation", "ContactSheet")
               if n not in names]
    if missing:
        pytest.skip(reason=f"face_capture.yaml needs {missing}, which are not installed")
    r = _run(["run", str(ROOT / "graphs" / "face_capture.yaml"), "--out", str(tmp_path / "out")],
             tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    from nodes.io.images import read_image

    for n in ("left", "front", "right", "top"):
        px, _ = read_image(str(tmp_path / "out" / "relit" / f"{n}.exr"))
        assert px.shape == (128, 128, 3) and np.isfinite(px).all() and px.max() > 0.2
    assert (tmp_path / "out" / "capture_sheet.png").stat().st_size > 10_000


BAD = """graphkit: 1
name: bad_input
params: {{data: ., azimuth: 0.0}}
nodes:
  photo: {{type: LoadImage, params: {{path: "${{params.data}}/photo.exr"}}}}
  mesh: {{type: LoadMesh, params: {{path: "${{params.data}}/mesh.ply"}}}}
  camera: {{type: LoadCameraJson, params: {{path: "${{params.data}}/camera.json"}}}}
  face: {{type: MeshMask, inputs: {{mesh: mesh.mesh, camera: camera.camera}}}}
  {body}
"""


@pytest.mark.parametrize("case", ["camera_size", "light_behind", "empty_skin", "mesh_behind", "mesh_beside",
                                  "pose_inverted", "light_inside", "ortho_camera_file", "probe_camera_size"])
def test_bad_inputs_exit_2_naming_node_and_port(tmp_path, case):
    import trimesh

    for f in DATA.iterdir():
        shutil.copy(f, tmp_path / f.name)
    if case in ("mesh_behind", "mesh_beside", "pose_inverted"):
        m = trimesh.load(tmp_path / "mesh.ply", process=False)
        if case == "mesh_behind":
            m.apply_translation([0, 0, -5000.0])
            m.export(tmp_path / "mesh.ply")
            want = "the mesh is behind the camera"
        elif case == "mesh_beside":
            m.apply_translation([3000.0, 0, 0])
            m.export(tmp_path / "mesh.ply")
            want = "the mesh is beside the camera"
        else:  # the camera's own pose (camera → world) given as world_to_camera
            cam = json.loads((tmp_path / "camera.json").read_text())
            T = np.eye(4)
            T[:3, 3] = [0.0, 0.0, -2400.0]  # the camera 2.4 m in front of the head, the head at the origin
            m.apply_translation([0, 0, -2400.0])
            m.export(tmp_path / "mesh.ply")
            cam["world_to_camera"] = T.tolist()  # should be the inverse
            (tmp_path / "camera.json").write_text(json.dumps(cam))
            want = "camera → world"
        body = """rmap: {type: ReflectanceMap, inputs: {image: photo.image, mesh: mesh.mesh, camera: camera.camera, skin: face.mask}}
outputs: {map: rmap.map}"""
        expect = ("'face' (MeshMask), port 'mesh'", want)
    elif case == "light_inside":
        body = """mat: {type: FitSkinPhong, inputs: {image: photo.image, skin: face.mask, mesh: mesh.mesh, camera: camera.camera, light: flash.light}}
  flash: {type: MakeLight, params: {kind: point, position_m: [0.0, 0.0, 2.5]}}
  lamp: {type: MakeLight, params: {kind: point, position_m: [0.0, 0.0, 2.48]}}
  render: {type: Render, inputs: {mesh: mesh.mesh, camera: camera.camera, material: mat.material, lights: [lamp.light]}}
outputs: {m: mat.material}"""
        expect = ("'mat' (FitSkinPhong), port 'light'", "inside the mesh")
    elif case == "ortho_camera_file":
        (tmp_path / "camera.json").write_text(json.dumps(
            {"width": 128, "height": 128, "type": "orthographic", "scale": 400.0, "cx": 64, "cy": 64}))
        body = """rmap: {type: ReflectanceMap, inputs: {image: photo.image, mesh: mesh.mesh, camera: camera.camera, skin: face.mask}}
outputs: {map: rmap.map}"""
        expect = ("'camera' (LoadCameraJson), port 'path'", "camera.json: unknown field 'type'; did you mean projection?")
    elif case == "probe_camera_size":
        body = """probe_photo: {type: LoadImage, params: {path: "${params.data}/probe.exr"}}
  small: {type: LoadCameraJson, params: {path: "${params.data}/small.json"}}
  probe: {type: ProbeLight, inputs: {probe: probe_photo.image, camera: small.camera}, params: {centre_x: 64.0, centre_y: 64.0, radius: 28.45}}
outputs: {light: probe.light}"""
        cam = json.loads((tmp_path / "camera.json").read_text())
        cam.update(width=64, height=64, cx=32.0, cy=32.0)
        (tmp_path / "small.json").write_text(json.dumps(cam))
        expect = ("'probe' (ProbeLight), port 'camera'", "sizes differ: probe is 128×128×3, camera is 64×64")
    elif case == "camera_size":
        cam = json.loads((tmp_path / "camera.json").read_text())
        cam.update(width=200, cx=100.0)
        (tmp_path / "camera.json").write_text(json.dumps(cam))
        body = """rmap: {type: ReflectanceMap, inputs: {image: photo.image, mesh: mesh.mesh, camera: camera.camera, skin: face.mask}}
outputs: {map: rmap.map}"""
        expect = ("'rmap' (ReflectanceMap), port 'camera'", "sizes differ: image is 128×128×3, camera is 200×128")
    elif case == "light_behind":
        body = """flash: {type: MakeLight, params: {azimuth_deg: 180.0}}
  fit: {type: FitSkinPhong, inputs: {image: photo.image, skin: face.mask, mesh: mesh.mesh, camera: camera.camera, light: flash.light}}
outputs: {m: fit.material}"""
        expect = ("'fit' (FitSkinPhong), port 'light'", "behind the face")
    else:
        body = """rmap: {type: ReflectanceMap, inputs: {image: photo.image, mesh: mesh.mesh, camera: camera.camera, skin: nobody.mask}}
  nobody: {type: MeshMask, inputs: {mesh: away.mesh, camera: camera.camera}}
  away: {type: LoadMesh, params: {path: "${params.data}/away.ply"}}
outputs: {map: rmap.map}"""
        import trimesh

        m = trimesh.load(tmp_path / "mesh.ply", process=False)
        m.apply_translation([0, 0, -5000.0])  # behind the camera: an empty skin mask
        m.export(tmp_path / "away.ply")
        expect = ("'nobody' (MeshMask), port 'mesh'", "the mesh is behind the camera")
    (tmp_path / "g.yaml").write_text(BAD.format(body=body))
    r = _run(["run", "g.yaml", "--out", "out"], tmp_path)
    assert r.returncode == 2, (r.returncode, r.stderr[-1500:])
    for e in expect:
        assert e in r.stderr, r.stderr[-1500:]
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())  # nothing partial


def test_face_relight_demo_runs(tmp_path):
    """The README demo: astronaut → FaceMesh → … → 8 relit EXRs + a contact sheet."""
    from graphkit.registry import default_registry

    names = default_registry().node_names()
    missing = [n for n in ("FaceMesh", "SkinSegment", "ContactSheet") if n not in names]
    if missing:
        pytest.skip(reason=f"face_relight.yaml needs {missing}, which are not installed")
    r = _run(["run", str(ROOT / "graphs" / "face_relight.yaml"), "--out", str(tmp_path / "out")],
             tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    from nodes.io.images import read_image

    imgs = {}
    for n in ("left60", "left30", "front", "right30", "right60", "top", "two_lights", "overexposed"):
        px, _ = read_image(str(tmp_path / "out" / "relit" / f"{n}.exr"))
        # the face at the photo's own pixel scale (the astronaut's face is ~115 px wide in the
        # 512² photo): a crop, not a magnified 320² view
        assert px.shape[2] == 3 and px.shape[0] == px.shape[1] and 100 <= px.shape[0] <= 200
        assert np.isfinite(px).all()
        imgs[n] = px
    # light from the image's left brightens the left half of the face, and vice versa
    def halves(px):
        lum = px.mean(-1)
        cov = lum > 0
        w = px.shape[1] // 2
        return lum[:, :w][cov[:, :w]].mean(), lum[:, w:][cov[:, w:]].mean()
    l, r_ = halves(imgs["left60"])
    assert l > 1.15 * r_
    l, r_ = halves(imgs["right60"])
    assert r_ > 1.15 * l
    assert imgs["overexposed"].max() == pytest.approx(1.0, abs=1e-3)
    assert (tmp_path / "out" / "contact_sheet.png").stat().st_size > 50_000
    # the whole photograph relit (issue 26): the photo's size; outside the face (the neck below
    # the chin, the hair above the brow) the light changed with the face, not left as it was
    import skimage.data

    from nodes.common.color import srgb_to_linear

    photo = srgb_to_linear(skimage.data.astronaut() / 255.0)
    for n in ("left60", "front", "right30", "top", "two_lights"):
        px, _ = read_image(str(tmp_path / "out" / "relit" / f"portrait_{n}.exr"))
        assert px.shape == photo.shape and np.isfinite(px).all()
        assert abs(np.log(px[176:184, 200:235].mean() / photo[176:184, 200:235].mean())) > 0.1, n  # the neck
    jpg, integer = read_image(str(tmp_path / "out" / "relit" / "portrait_right30.jpg"))
    assert integer and jpg.shape == photo.shape
    assert (tmp_path / "out" / "portraits.png").stat().st_size > 200_000
