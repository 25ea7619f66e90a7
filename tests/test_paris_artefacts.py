"""Issue 26 item 3: no artefacts at the lips and the mesh border.

* The lips: the astronaut relit from the top (graphs/face_relight.yaml's `top 45`) had a
  bright streak along the lower lip: the fitted mesh's lips miss the photo's by a few pixels,
  so its lit lower-lip normals multiplied the photo's lip highlight while the mouth above was
  shaded dark.  Counted here as bright outliers of relit / photo inside the mouth region.
* The border: Render's coverage was binary, a staircase along the silhouette; with
  ``antialias`` each silhouette pixel covers the fraction of it the mesh covers (checked on a
  disc against a 16×16 supersampled truth)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import Camera, Light
from nodes.paris.models import PhongMaterial
from nodes.paris.render import Render, mouth_region

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _disc(n_seg=240, r=0.9, z=4.0):
    import trimesh

    a = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    V = np.vstack([[0.0, 0.0, z], np.stack([r * np.cos(a), r * np.sin(a), np.full(n_seg, z)], 1)])
    F = np.array([[0, 1 + i, 1 + (i + 1) % n_seg] for i in range(n_seg)])
    return trimesh.Trimesh(V, F, process=False), a


def _true_coverage(cam: Camera, r: float, z: float, k: int = 16) -> np.ndarray:
    """The fraction of each pixel inside the disc's projection (a circle: the disc faces the
    camera), by k×k samples per pixel."""
    H, W = cam.height, cam.width
    yy, xx = np.mgrid[0:H * k, 0:W * k]
    u, v = (xx + 0.5) / k, (yy + 0.5) / k
    R = r * cam.fx / z
    inside = (u - cam.cx) ** 2 + (v - cam.cy) ** 2 < R * R
    return inside.reshape(H, k, W, k).mean((1, 3))


@pytest.mark.parametrize("antialias, lo, hi", [(False, 0.15, 1.0), (True, 0.0, 0.05)])
def test_silhouette_coverage_is_the_covered_fraction(antialias, lo, hi):
    """Mean |coverage − true fraction| over the pixels the outline crosses: ~0.21 binary
    (the staircase), ~0.02 antialiased; the image is the lit colour × the fraction."""
    mesh, _ = _disc()
    cam = Camera(width=56, height=48, fx=60.3, fy=60.3, cx=27.7, cy=24.2)
    mat = PhongMaterial(diffuse=(0.5, 0.5, 0.5), specular=0.0, shininess=10.0)
    out = Render(Render.Params(antialias=antialias, shadows=False, eye_highlights="off")).compute(
        mesh=mesh, camera=cam, material=mat, lights=[Light(direction=(0.0, 0.0, -1.0))])
    cov, img = out["coverage"].alpha, out["image"].pixels
    true = _true_coverage(cam, 0.9, 4.0)
    edge = (true > 0) & (true < 1)
    err = float(np.abs(cov - true)[edge].mean())
    assert lo <= err <= hi, err
    assert abs(float(cov.sum() - true.sum())) < (0.02 * edge.sum() if antialias else edge.sum())
    full = img[true == 1].mean(0)
    assert np.allclose(img[edge], cov[edge][:, None] * full, atol=1e-4)


@pytest.fixture(scope="module")
def astronaut_top(tmp_path_factory):
    """The demo's face relit from the top (its `top 45` close-up) and what it is made from."""
    from graphkit.api import run_graph
    from graphkit.registry import default_registry

    if "FaceMesh" not in default_registry().node_names():
        pytest.skip(reason="needs the graphkit-mediapipe plugin (FaceMesh)")
    run = run_graph(ROOT / "graphs" / "face_relight.yaml", cache=tmp_path_factory.mktemp("cache"),
                    outputs=["top"], jobs=2)
    names = ("view.camera", "view.image", "smooth.mesh", "fit.material", "l_top.light", "detail.ratio",
             "face.camera", "fit.light", "top.image")
    return {n: run.value(n) for n in names}


def _bright_outliers(v, image) -> tuple[int, int]:
    """(pixels of the mouth region where relit / photo > 1.5 × its median there, the region's
    pixels)."""
    alpha, _ = mouth_region(v["smooth.mesh"], v["view.camera"])
    m = alpha > 0.5
    photo = v["view.image"].pixels[..., :3].mean(2)
    ratio = image[..., :3].mean(2) / np.maximum(photo, 1e-3)
    return int((ratio[m] > 1.5 * np.median(ratio[m])).sum()), int(m.sum())


def test_no_bright_streak_at_the_lips(astronaut_top):
    """The demo's `top 45` (mouth: photo, the default): ≤ 5 % bright outliers in the mouth
    (measured 18 of 774); shaded as skin (the old behaviour) 238 of 774."""
    v = astronaut_top
    n, total = _bright_outliers(v, v["top.image"].pixels)
    assert total > 300 and n <= 0.05 * total, (n, total)
    inputs = dict(mesh=v["smooth.mesh"], camera=v["view.camera"], material=v["fit.material"],
                  lights=[v["l_top.light"]], detail=v["detail.ratio"], texture_camera=v["face.camera"],
                  ambient=v["fit.light"])
    skin = Render(Render.Params(mouth="skin", ambient_gain=0.35)).compute(**inputs)["image"].pixels
    n_skin, _ = _bright_outliers(v, skin)
    assert n_skin > 0.2 * total, (n_skin, total)  # the measure sees the streak


def test_mouth_region_needs_the_mediapipe_ids(astronaut_top):
    mesh, _ = _disc()
    cam = Camera(width=56, height=48, fx=60.3, fy=60.3, cx=27.7, cy=24.2)
    assert mouth_region(mesh, cam) is None
    alpha, height = mouth_region(astronaut_top["smooth.mesh"], astronaut_top["view.camera"])
    assert 10 < height < 40 and alpha.max() == 1.0 and alpha.min() == 0.0
