"""FaceMesh (graphkit-mediapipe plugin) on scikit-image's astronaut photo.

Outside reference: mediapipe's own landmarks on the photo; the node's camera must reproject the
mesh onto them, and the masks must sit where faces have them.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("graphkit_mediapipe", reason="plugin graphkit-mediapipe not installed (make installs it)")
pytest.importorskip("mediapipe", reason="mediapipe not installed (pip install --no-deps mediapipe==0.10.14)")

from graphkit import BadInput, Image  # noqa: E402


@pytest.fixture(scope="module")
def astronaut():
    import skimage.data

    from nodes.common.color import srgb_to_linear

    return Image(srgb_to_linear(skimage.data.astronaut() / 255.0))


@pytest.fixture(scope="module")
def result(astronaut):
    from graphkit_mediapipe.facemesh import FaceMesh

    return FaceMesh().compute(image=astronaut)


def test_registered_by_entry_point():
    from graphkit.registry import discover

    reg = discover()
    assert "FaceMesh" in reg.node_names()
    assert reg.node_class("FaceMesh").__module__ == "graphkit_mediapipe.facemesh"


def test_mesh_and_camera(result):
    mesh, cam, lm = result["mesh"], result["camera"], result["landmarks"]
    assert mesh.vertices.shape == (468, 3) and lm.shape == (468, 2)
    assert mesh.faces.shape == (852, 3)
    assert mesh.is_winding_consistent
    assert (cam.width, cam.height) == (512, 512)
    uv, z = cam.project(mesh.vertices)
    assert np.all(z > 0)
    assert np.abs(uv - lm).max() < 0.5
    # triangles face the camera: normals towards -z (OpenCV camera frame), area-weighted
    n = mesh.face_normals * mesh.area_faces[:, None]
    assert n[:, 2].sum() < -0.5 * mesh.area_faces.sum()  # a face is curved: about -0.6
    # metric-ish: eye centres 63 mm apart, face some 12-25 cm tall
    eyes = [mesh.vertices[[33, 133]].mean(0), mesh.vertices[[263, 362]].mean(0)]
    assert np.linalg.norm(eyes[0] - eyes[1]) == pytest.approx(63.0, rel=0.02)  # scale set in pixel space
    height = np.ptp(mesh.vertices[:, 1])
    assert 120 < height < 250  # hairline to chin


def test_landmarks_match_mediapipe(result, astronaut):
    import mediapipe as mp
    import skimage.data

    with mp.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=1) as fm:
        r = fm.process(skimage.data.astronaut())
    ref = np.array([[p.x * 512, p.y * 512] for p in r.multi_face_landmarks[0].landmark])
    # the node re-encodes linear → sRGB uint8: at most a rounding difference in the input
    assert np.abs(ref - result["landmarks"]).max() < 1.0


def _centroid(m):
    ys, xs = np.nonzero(m.alpha > 0.5)
    return xs.mean(), ys.mean()


def test_masks_plausible(result):
    lm = result["landmarks"]
    face = result["face"].alpha
    nose_tip = lm[1]
    for k in ("face", "eyes", "brows", "lips", "cheeks", "nostrils"):
        a = result[k].alpha
        assert a.shape == (512, 512) and a.dtype == np.float32
        assert set(np.unique(a)) <= {0.0, 1.0}
        assert a.sum() > 20, k
        if k != "face":  # every region lies (almost) inside the face oval
            assert (a * face).sum() > 0.95 * a.sum(), k
    assert 3000 < face.sum() < 0.2 * face.size
    _, y_eyes = _centroid(result["eyes"])
    _, y_brows = _centroid(result["brows"])
    _, y_lips = _centroid(result["lips"])
    _, y_nostrils = _centroid(result["nostrils"])
    _, y_cheeks = _centroid(result["cheeks"])
    assert y_brows < y_eyes < nose_tip[1] < y_lips  # image y grows downwards
    assert nose_tip[1] - 5 < y_nostrils < y_lips
    assert y_eyes < y_cheeks < y_lips
    # two eyes, two brows, two cheeks, two nostrils: left/right of the nose tip
    for k in ("eyes", "brows", "cheeks", "nostrils"):
        ys, xs = np.nonzero(result[k].alpha)
        assert (xs < nose_tip[0]).sum() > 5 and (xs > nose_tip[0]).sum() > 5, k
    # eyes and lips are darker/redder than cheeks in the photo: sanity of placement
    import skimage.data

    img = skimage.data.astronaut().astype(float)
    lips = img[result["lips"].alpha > 0].mean(0)
    cheeks = img[result["cheeks"].alpha > 0].mean(0)
    assert lips[0] / lips[1] > cheeks[0] / cheeks[1]


def test_no_face_is_bad_input():
    from graphkit_mediapipe.facemesh import FaceMesh

    with pytest.raises(BadInput) as e:
        FaceMesh().compute(image=Image(np.full((128, 128, 3), 0.2, np.float32)))
    assert e.value.port == "image" and "no face" in e.value.message


def test_no_face_cli_exit_2(tmp_path):
    import OpenImageIO as oiio

    grey = tmp_path / "grey.png"
    out = oiio.ImageOutput.create(str(grey))
    out.open(str(grey), oiio.ImageSpec(96, 96, 3, "uint8"))
    out.write_image(np.full((96, 96, 3), 128, np.uint8))
    out.close()
    graph = tmp_path / "g.yaml"
    graph.write_text(
        "graphkit: 1\nname: noface\nnodes:\n"
        "  photo:\n    type: LoadImage\n    params: {path: grey.png}\n"
        "  fm:\n    type: FaceMesh\n    inputs: {image: photo.image}\n"
        "outputs:\n  landmarks: fm.landmarks\n")
    exe = Path(sys.executable).with_name("graphkit")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "graphkit"]
    r = subprocess.run(cmd + ["run", str(graph), "--out", str(tmp_path / "out"),
                              "--cache", str(tmp_path / "cache"), "-q"],
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONWARNINGS": "ignore"})
    msg = r.stdout + r.stderr
    assert r.returncode == 2, msg
    assert "fm" in msg and "FaceMesh" in msg and "image" in msg and "no face" in msg, msg
    assert "Traceback" not in msg, msg
