"""SmoothMesh (issue 11 item 7): Loop subdivision keeps the FaceMesh's facet lines out of the
shaded face, hence the detail texture, of the astronaut photo; the mediapipe vertex ids survive
it."""
import numpy as np
import pytest
import trimesh

from graphkit import Image, Mask
from nodes.paris.mesh import SmoothMesh
from nodes.paris.reflectance import ReflectanceMap
from nodes.paris.render import ShadeFace, _mediapipe_ids


def kink_ratio(img, ok, coarse, cam, h=1.0) -> float:
    """How much sharper the image bends across the edges of ``coarse`` than beside them: the rms
    second difference across each edge (at 30, 50, 70 % of its length, steps of ``h`` pixels)
    over the rms second difference 2h to either side, where both lie in ``ok``.  About 1 when
    the edges are not special; > 1 for creases along them."""
    from scipy import ndimage

    e = coarse.edges_unique
    xy, _ = cam.project(coarse.vertices)
    a, b = xy[e[:, 0]], xy[e[:, 1]]
    L = np.linalg.norm(b - a, axis=1)
    t = (b - a) / np.maximum(L, 1e-9)[:, None]
    perp = np.stack([-t[:, 1], t[:, 0]], 1)
    H, W = img.shape
    on, off = [], []
    for f in (0.3, 0.5, 0.7):
        m = a + (b - a) * f
        pts = np.stack([m + k * h * perp for k in range(-3, 4)], 1)  # E × 7 × 2
        v = ndimage.map_coordinates(img, [pts[..., 1] - 0.5, pts[..., 0] - 0.5], order=1)
        ix = np.clip(pts[..., 0].astype(int), 0, W - 1)
        iy = np.clip(pts[..., 1].astype(int), 0, H - 1)
        use = ok[iy, ix].all(1) & (L > 6)
        dd = v[:, :-2] - 2 * v[:, 1:-1] + v[:, 2:]  # at k = −2 … 2
        on.append(dd[use, 2])
        off.append(np.concatenate([dd[use, 0], dd[use, 4]]))
    on, off = np.concatenate(on), np.concatenate(off)
    return float(np.sqrt(np.mean(on ** 2) / np.mean(off ** 2)))


def test_no_facet_lines_in_the_astronaut_shaded_face():
    """The detail texture is the photo divided by the shaded face, so a crease of the shaded face
    along a mesh edge is a line in every relit image (the old demo's lines across forehead and
    cheeks).  On the astronaut's 852-triangle FaceMesh the interpolated normals bend at every
    edge: lit, they bend 1.7× more sharply across the edges than beside them; on the
    Loop-subdivided surface the old edges are no longer special, nor in the default pipeline's
    shaded face.  (The old 2° map adds albedo speckle everywhere, edges or not: compare
    docs/face_relight.png with its earlier version.)"""
    from scipy.ndimage import binary_dilation, binary_erosion

    from graphkit.registry import default_registry
    from nodes.paris.render import MakeLight, surface

    reg = default_registry()
    if "FaceMesh" not in reg.node_names():
        pytest.skip(reason="needs the FaceMesh node (plugin graphkit-mediapipe, installed by make)")
    import skimage.data

    from nodes.common.color import srgb_to_linear

    photo = Image(srgb_to_linear(skimage.data.astronaut() / 255.0).astype(np.float32))
    fm = reg.node_class("FaceMesh")().compute(image=photo)
    cam, coarse = fm["camera"], fm["mesh"]
    feat = binary_dilation(np.maximum.reduce([fm[k].alpha for k in ("eyes", "brows", "lips", "nostrils")]) > 0.5,
                           iterations=6)
    skin = (fm["face"].alpha > 0.5) & ~feat
    flash = MakeLight().compute(camera=cam)
    light = np.array([-0.5, -0.5, -0.7]) / np.linalg.norm([-0.5, -0.5, -0.7])
    meshes = {"coarse": coarse, "loop2": SmoothMesh().compute(mesh=coarse)}
    ok = skin & binary_erosion(surface(coarse, cam).coverage, iterations=8)
    lit, shaded = {}, {}
    for name, mesh in meshes.items():
        s = surface(mesh, cam)
        lam = np.zeros(s.coverage.shape)
        lam[s.coverage] = np.clip(s.normals @ light, 0, 1)  # the normals, lit from the upper left
        lit[name] = kink_ratio(lam, ok, coarse, cam)
    for name, mesh, cluster in (("old: coarse, 2° map", coarse, 2.0), ("new: Loop ×2, map from the data", meshes["loop2"], None)):
        rm = ReflectanceMap(ReflectanceMap.Params(cluster_deg=cluster)).compute(
            image=photo, mesh=mesh, camera=cam, skin=Mask(skin.astype(np.float32)), light=flash)
        sh = ShadeFace().compute(mesh=mesh, camera=cam, map=rm["map"], light=flash)["image"].pixels
        shaded[name] = kink_ratio(sh.mean(-1).astype(np.float64), ok, coarse, cam)
    print("\ncrease across / beside the FaceMesh edges: lit normals", {k: round(v, 3) for k, v in lit.items()},
          "; shaded face", {k: round(v, 3) for k, v in shaded.items()})
    assert lit["coarse"] > 1.4 and lit["loop2"] < 1.15
    assert shaded["new: Loop ×2, map from the data"] < 1.15


def test_source_vertex_keeps_the_mediapipe_ids():
    xs, ys = np.meshgrid(np.linspace(-1, 1, 18), np.linspace(-1, 1, 26))
    V = np.stack([xs.ravel(), ys.ravel(), 4 + 0.1 * xs.ravel() ** 2], 1)  # 468 vertices
    F = []
    for j in range(25):
        for i in range(17):
            a = j * 18 + i
            F += [[a, a + 1, a + 19], [a, a + 19, a + 18]]
    m = trimesh.Trimesh(V, F, process=False)
    assert np.array_equal(_mediapipe_ids(m), np.arange(468))
    s = SmoothMesh().compute(mesh=m)
    assert len(s.faces) == 16 * len(m.faces)
    assert np.array_equal(_mediapipe_ids(s), np.arange(468)) and len(s.vertices) > 468
    # the same vertices (moved by Loop's rule, a little; corners of the boundary most), in order
    shift = np.linalg.norm(s.vertices[:468] - V, axis=1)
    assert np.median(shift) < 0.02 and shift.max() < 0.5
    # the attribute survives the cache (the Mesh port's parts)
    from graphkit.types import MESH

    back = MESH.from_parts(*MESH.to_parts(s))
    assert np.array_equal(_mediapipe_ids(back), np.arange(468))


def test_bad_meshes_are_refused_naming_the_port():
    """No triangles: the shared render.check_mesh; NaN vertices: declared (finite=True), so the
    engine refuses them before compute."""
    from graphkit import BadInput
    from graphkit.contract import compute_checked

    m = trimesh.creation.icosphere(subdivisions=1)
    with pytest.raises(BadInput) as e:
        compute_checked(SmoothMesh(), mesh=trimesh.Trimesh(m.vertices, np.zeros((0, 3), np.int64), process=False))
    assert e.value.port == "mesh" and e.value.message == "the mesh has no triangles"
    bad = m.copy()
    bad.vertices[3] = [np.inf, 0, np.nan]
    with pytest.raises(BadInput) as e:
        compute_checked(SmoothMesh(), mesh=bad)
    assert e.value.port == "mesh" and e.value.message.startswith("holds 1 NaN and 1 Inf values"), e.value.message
