"""nodes/loscos/mitsuba_scene.py: Mitsuba 3 scene dicts → Loscos scene files, checked against
Mitsuba's own ray casting (the shape each camera ray hits, where, and its normal)."""
import numpy as np
import pytest

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the outside reference for the converter")

from nodes.loscos import geometry as G  # noqa: E402
from nodes.loscos.mitsuba_ref import set_variant  # noqa: E402
from nodes.loscos.meshes import mesh_polygons  # noqa: E402
from nodes.loscos.mitsuba_scene import MitsubaSceneError, scene_file  # noqa: E402
from nodes.loscos.scene import parse_scene  # noqa: E402
from nodes.loscos.textures import rays_at  # noqa: E402


def mitsuba_hits(d, n=12):
    """Per pixel of an n×n grid of pixel centres: Mitsuba's ray (o, d) and what it hits."""
    scene = mi.load_dict(d)
    sensor = scene.sensors()[0]
    W, H = sensor.film().crop_size()
    out = []
    for i in range(n):
        for j in range(n):
            x, y = (j + 0.31) * W / n, (i + 0.67) * H / n  # off the box's diagonals
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / W, y / H), mi.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            hit = bool(si.is_valid())
            out.append((x, y, np.array(ray.o), np.array(ray.d), hit,
                        si.shape.id() if hit else None, float(si.t) if hit else np.inf,
                        np.array(si.n) if hit else None))
    return out


def check_against_mitsuba(d, doc, n=12):
    sc, cam, _ = parse_scene(doc)
    po, pu, pv, pn, _ = G.frame(sc.verts)
    hits = mitsuba_hits(d, n)
    X = np.array([h[0] for h in hits])
    Y = np.array([h[1] for h in hits])
    o, dirs = rays_at(cam, X, Y)
    for (_, _, _, md, _, _, _, _), dd in zip(hits, dirs):
        assert np.allclose(dd, md, atol=1e-5)
    idx, t, _, _ = G.ray_first_hit(o, dirs, po, pu, pv, pn, two_sided=True)
    seen = 0
    for k, (_, _, mo, md, hit, sid, mt, mn) in enumerate(hits):
        assert hit == (idx[k] >= 0)
        if not hit:
            continue
        seen += 1
        if sid:  # Mitsuba merges meshes that share a BSDF into one shape without an id
            assert sc.names[idx[k]].split(".")[0] == sid
        # Mitsuba starts its rays at the near clip plane: compare the points hit
        assert np.allclose(o[k] + t[k] * dirs[k], mo + mt * md, atol=1e-4)
        assert np.dot(pn[idx[k]], mn) > 0.999  # same front side (emitters are one-sided)
    return seen


def test_cornell_box_converts():
    set_variant()
    d = mi.cornell_box()
    doc = scene_file(d, photo="cornell.exr")
    assert doc["camera"]["width"] == 256 and doc["camera"]["fov_deg"] == pytest.approx(39.3077)
    assert [x["name"] for x in doc["lights"]] == ["light"]
    assert doc["lights"][0]["emittance"] == pytest.approx(np.pi * np.array([18.387, 13.9873,
                                                                               6.75357]), rel=1e-6)
    assert check_against_mitsuba(d, doc) > 100
    assert "emittance" not in scene_file(d, emittance=False)["lights"][0]


def test_meshes_flipped_shapes_and_fov_axes(tmp_path):
    """An OBJ box (triangles, paired back into faces), an inward cube as the room, a flipped
    rectangle, a twosided BSDF and a vertical field of view on a wide film."""
    import trimesh

    set_variant()
    T = mi.ScalarTransform4f
    box = trimesh.creation.box(extents=[0.5, 0.8, 0.4])
    box.export(tmp_path / "box.obj")
    d = {"type": "scene",
         "room": {"type": "cube", "flip_normals": True, "to_world": T().scale([2, 1.5, 2.5]),
                  "bsdf": {"type": "twosided", "b": {"type": "diffuse",
                                                     "reflectance": {"type": "rgb",
                                                                     "value": [0.7, 0.6, 0.5]}}}},
         "crate": {"type": "obj", "filename": str(tmp_path / "box.obj"),
                   "to_world": T().translate([0.4, -1.1, -0.6]) @ T().rotate([0, 1, 0], 25)},
         "panel": {"type": "rectangle", "flip_normals": True,
                   "to_world": T().translate([-0.9, 0.2, -1.2]) @ T().rotate([0, 1, 0], 180)
                   @ T().scale(0.3),
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [4, 4, 3]}}},
         "sensor": {"type": "perspective", "fov": 50, "fov_axis": "y",
                    "to_world": T().look_at(origin=[0.3, 0.2, 2.2], target=[0, -0.3, 0],
                                            up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 96, "height": 64}}}
    doc = scene_file(d, base_dir=str(tmp_path))
    names = [p["name"] for p in doc["polygons"]]
    assert sum(n.startswith("crate.") for n in names) == 6  # 12 triangles → 6 faces
    assert doc["camera"]["fov_deg"] == pytest.approx(2 * np.degrees(np.arctan(
        np.tan(np.radians(25)) * 96 / 64)), rel=1e-6)
    assert check_against_mitsuba(d, doc) > 100


def test_mesh_pairing_keeps_lone_triangles():
    """Pairs become parallelograms; a triangle with no partner stays a triangle (a, b, c, c)
    (triangles are first-class since issue 27; they were refused before)."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], float)
    quads = mesh_polygons(V, np.array([[0, 1, 2], [0, 2, 3]]), "m")
    assert quads.shape == (1, 4, 3)
    n = np.cross(quads[0, 1] - quads[0, 0], quads[0, 3] - quads[0, 0])
    assert n[2] > 0 and np.allclose(quads[0, 2], quads[0, 1] + quads[0, 3] - quads[0, 0])
    polys = mesh_polygons(V, np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]]), "m")
    assert polys.shape == (2, 4, 3)
    assert np.array_equal(polys[1], V[[1, 4, 2, 2]])
    assert mesh_polygons(V, np.array([[0, 1, 2], [0, 2, 3]]), "m", merge=False).shape == (2, 4, 3)


@pytest.mark.parametrize("entry,match", [
    ({"type": "envmap", "filename": "sky.exr"}, "'envmap' emitter has no counterpart"),
    ({"type": "rectangle", "bsdf": {"type": "roughconductor"}}, "BSDF 'roughconductor'"),
    ({"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "bitmap"}}},
     "'bitmap' texture"),
    ({"type": "rectangle", "bsdf": {"type": "ref", "id": "nope"}}, "'nope' is not defined"),
    ({"type": "sphere"}, "'sphere' has no counterpart"),
])
def test_converter_names_what_it_cannot_take(entry, match):
    d = {"type": "scene", "thing": entry,
         "sensor": {"type": "perspective", "fov": 40, "to_world": np.eye(4)}}
    with pytest.raises(MitsubaSceneError, match=f"thing[:.].*{match}"):
        scene_file(d)
