"""Triangle meshes in the Loscos nodes (issue 27 item 1): triangles first-class in the
hierarchy (1-to-4 subdivision), mesh files (OBJ / PLY / GLB through trimesh) as scenes, the
builtin scenes as meshes giving the same images, and bad mesh input refused by name."""
from __future__ import annotations

import os

import numpy as np
import pytest
import yaml

from graphkit import BadInput, Context
from nodes.common import rays
from nodes.common.color import linear_to_srgb
from nodes.loscos import geometry as G
from nodes.loscos import hierarchy as HR
from nodes.loscos.ports import RoomScene
from nodes.loscos.scene import DATA, example_room, parse_scene

TRI = np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 1, 0]])  # (a, b, c, c), normal +z


def psnr(a, b, mask=None):
    enc = lambda x: np.clip(linear_to_srgb(np.clip(x, 0, None)), 0, 1)  # noqa: E731
    d = (enc(a) - enc(b)) ** 2
    return float(10 * np.log10(1.0 / np.mean(d if mask is None else d[mask])))


def as_triangles(sc: RoomScene) -> RoomScene:
    """Every parallelogram (a, b, c, d) split into the triangles (a, b, c), (a, c, d)."""
    V, rows = [], []
    for i, v in enumerate(sc.verts):
        V += [v[[0, 1, 2, 2]], v[[0, 2, 3, 3]]]
        rows += [i, i]
    r = np.array(rows)
    return RoomScene([f"{sc.names[i]}.{k % 2}" for k, i in enumerate(r)], np.array(V),
                     sc.reflectance[r], sc.emittance[r], [sc.light[i] for i in r],
                     emit_given=sc.emit_given[r])


# -- the hierarchy's triangles ------------------------------------------------------------


def test_triangle_subdivision_tiles_the_triangle():
    h = HR.Hierarchy.roots(TRI[None])
    assert h.area(np.array([0]))[0] == pytest.approx(1.0)
    h.subdivide(np.array([0]))
    h.subdivide(h.children(np.array([0])).ravel())  # level 2: 16 triangles, 4 of them flipped
    lv = h.leaves
    assert len(lv) == 16 and h.flipped[lv].sum() == 6
    assert h.area(lv).sum() == pytest.approx(1.0) and np.allclose(h.area(lv), 1 / 16)
    o, u, v, n, a = h.geom(lv)
    assert np.allclose(0.5 * np.linalg.norm(np.cross(u, v), axis=1), a)
    assert np.allclose(np.cross(u, v)[:, 2] > 0, True)  # flipped ones keep the front side
    # random points of the triangle: locate() finds the leaf that holds each one
    rng = np.random.default_rng(1)
    st = G.fold(rng.random((500, 2)), np.ones(500, bool))
    e = h.locate(np.zeros(500, np.int64), st[:, 0], st[:, 1])
    x = TRI[0] + st[:, :1] * (TRI[1] - TRI[0]) + st[:, 1:] * (TRI[2] - TRI[0])
    oo, uu, vv, _, _ = h.geom(e)
    du, dv = G.dual_basis(uu, vv)
    a_, b_ = np.einsum("nc,nc->n", x - oo, du), np.einsum("nc,nc->n", x - oo, dv)
    assert (a_ >= -1e-9).all() and (b_ >= -1e-9).all() and (a_ + b_ <= 1 + 1e-9).all()
    assert h.locate(np.array([0]), np.array([0.9]), np.array([0.9]))[0] == -1  # off the triangle


def test_triangle_form_factors_add_up_to_the_parallelogram():
    """F from a receiver to a parallelogram = the sum over its two triangles (contour
    integral, exact); and a parallelogram receiver's F = the area mean of its two halves'."""
    rec = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])  # faces +z
    snd = np.array([[0.2, 0.1, 1.0], [0.2, 1.1, 1.0], [1.3, 1.1, 1.0], [1.3, 0.1, 1.0]])  # -z
    def ff(r, s, tri_i, tri_j):
        o1, u1, v1, n1, _ = G.frame(r[None]); o2, u2, v2, n2, _ = G.frame(s[None])
        return G.element_form_factors(o1, u1, v1, n1, o2, u2, v2, n2, 6,
                                      tri_i=np.array([tri_i]), tri_j=np.array([tri_j]))[0]
    whole = ff(rec, snd, False, False)
    halves = ff(rec, snd[[0, 1, 2, 2]], False, True) + ff(rec, snd[[0, 2, 3, 3]], False, True)
    assert halves == pytest.approx(whole, rel=1e-12)
    recv = 0.5 * (ff(rec[[0, 1, 2, 2]], snd, True, False) + ff(rec[[0, 2, 3, 3]], snd, True, False))
    assert recv == pytest.approx(whole, rel=2e-3)


def test_triangle_occluders_in_both_ray_backends():
    """A segment through the triangle is blocked, one through the other half of its
    parallelogram is not, with the numpy reference and with Embree."""
    o, u, v, n, _ = G.frame(TRI[None])
    occ = (o, u, v, n, np.array([True]))
    p0 = np.array([[0.3, 0.3, -1], [1.5, 0.8, -1], [0.9, 0.45, -1]])
    p1 = p0 + [0, 0, 2]
    for b in ("numpy", "embree"):
        with rays.using(b):
            assert rays.occluded(p0, p1, occ).tolist() == [True, False, True], b


def test_camera_rays_first_polygon_in_both_ray_backends():
    """textures.first_hit: Embree names the same polygon and (s, t) as the float64 reference on
    the example room with a box, split into triangles, at 4×4 rays per pixel (the edges of the
    triangles' diagonals and of the box included)."""
    from nodes.loscos.textures import first_polygon, rays_at

    sc, cam, _ = example_room([[0.25, 0, 0, -0.2], [0, 0.3, 0, -0.7], [0, 0, 0.25, -0.3],
                               [0, 0, 0, 1]])
    verts = as_triangles(sc).verts
    Y, X = np.mgrid[0:cam.height:0.25, 0:cam.width:0.25] + 0.125
    o, d = rays_at(cam, X.ravel(), Y.ravel())
    f = np.linspace(0.05, 0.95, 7)[:, None, None, None]  # and rays at points on every triangle's edges
    on_edges = (verts[:, [0, 1, 2]] * (1 - f) + verts[:, [1, 2, 0]] * f).reshape(-1, 3)
    d = np.concatenate([d, on_edges - cam.position])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(cam.position, d.shape).copy()
    ref, ref_st = first_polygon(verts, o, d)
    with rays.using("embree"):
        got, got_st = first_polygon(verts, o, d)
    assert (ref >= 0).mean() > 0.6 and len(np.unique(ref)) > 12
    assert np.array_equal(got, ref), f"{(got != ref).sum()} of {len(ref)} rays differ"
    assert np.allclose(got_st, ref_st, atol=1e-9)


@pytest.mark.parametrize("n_poly, side", [(44, 128), (256, 128), (257, 127), (19_417, 14),
                                          (50_000, 9), (10**6, 4)])
def test_texture_side_keeps_128_until_the_texel_budget(n_poly, side):
    from nodes.loscos.textures import ProjectTextures, texture_side

    prm = ProjectTextures.Params()
    assert texture_side(n_poly, prm.resolution, prm.texel_budget) == side


COARSE = {"eps_bf": 0.5, "eps_bfv": 0.05, "min_area": 0.04, "max_level": 3}


def test_room_of_triangles_relights_like_the_room_of_parallelograms():
    """The example room (with a box) split into triangles: same relit images (≥ 35 dB)."""
    from nodes.loscos.radiosity import RadiositySolve, TextureRefine
    from nodes.loscos.relight import Relight, Unocclude
    from nodes.loscos.textures import ProjectTextures

    def run(node, params, **kw):
        return node(node.Params(**params), Context()).compute(**kw)

    box = [[0.25, 0, 0, -0.2], [0, 0.3, 0, -0.7], [0, 0, 0.25, -0.3], [0, 0, 0, 1]]
    sc, cam, photo = example_room(box)
    out = []
    for s in (sc, as_triangles(sc)):
        pr = run(ProjectTextures, {"resolution": 8}, scene=s, camera=cam, photo=photo)
        sol = run(RadiositySolve, COARSE, scene=s, projection=pr)["solution"]
        ref = run(TextureRefine, {"max_level": 3, "min_area": 0.02, "max_rounds": 1}, scene=s,
                  solution=sol, projection=pr)
        un = run(Unocclude, {}, solution=ref, projection=pr, photo=photo)["unoccluded"]
        out.append([run(Relight, {"light_scale": k}, solution=ref, unoccluded=un, projection=pr,
                        photo=photo).pixels for k in ({"A": 0.0}, {"B": 2.0})])
        if s is not sc:
            assert ref.P_tri is not None and ref.P_tri.all() and ref.flip.any()
    for a, b in zip(*out):
        assert psnr(a, b) >= 35.0


# -- mesh files -----------------------------------------------------------------------------


def mesh_doc(meshes, lights, **kw):
    return dict({"loscos_scene": 1, "camera": {"width": 8, "height": 8, "fov_deg": 60,
                                               "position": [0, 0, 3], "look_at": [0, 0, 0]},
                 "materials": {"w": [0.7, 0.7, 0.7]}, "meshes": meshes, "lights": lights}, **kw)


def write_glb(path, parts: dict):
    import trimesh

    sc = trimesh.Scene()
    for name, (V, F) in parts.items():
        sc.add_geometry(trimesh.Trimesh(V, F, process=False), geom_name=name, node_name=name)
    sc.export(path)


FLOOR = (np.array([[-1.0, -1, 1], [1, -1, 1], [1, -1, -1], [-1, -1, -1]]), np.array([[0, 1, 2], [0, 2, 3]]))
LAMP = (np.array([[-.2, .9, -.2], [.2, .9, -.2], [0, .9, .2]]), np.array([[0, 2, 1]]))  # faces down


def test_glb_parts_and_named_light(tmp_path):
    write_glb(tmp_path / "m.glb", {"floor": FLOOR, "lamp": LAMP})
    sc, _, _ = parse_scene(mesh_doc([{"file": "m.glb", "material": "w"}],
                                    [{"name": "lamp", "emittance": [5, 5, 5]}]), base_dir=str(tmp_path))
    assert sc.light_names == ["lamp"]
    tri = G.is_triangle(sc.verts)
    assert sc.names == ["floor.0", "lamp"] and tri.tolist() == [False, True]  # the pair merged
    assert G.frame(sc.verts)[4] == pytest.approx([4.0, 0.08])
    sc2, _, _ = parse_scene(mesh_doc([{"file": "m.glb", "material": "w", "merge": False}],
                                     [{"name": "lamp"}]), base_dir=str(tmp_path))
    assert G.is_triangle(sc2.verts).all() and len(sc2.verts) == 3
    assert not sc2.light_given().any()  # no emittance: estimated from the photograph


def test_obj_parts_are_its_materials_with_their_colours(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl floor\nKd 0.5 0.25 0.125\nnewmtl lamp\nKd 1 1 1\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv -1 -1 1\nv 1 -1 1\nv 1 -1 -1\nv -1 -1 -1\nv -.2 .9 -.2\nv .2 .9 -.2\n"
        "v 0 .9 .2\nusemtl floor\nf 1 2 3 4\nusemtl lamp\nf 5 7 6\n")
    sc, _, _ = parse_scene(mesh_doc([{"file": "m.obj", "parts": {"lamp": "w"}}],
                                    [{"name": "lamp", "emittance": [5, 5, 5]}]), base_dir=str(tmp_path))
    assert sc.reflectance[sc.names.index("floor.0")] == pytest.approx([0.5, 0.25, 0.125], abs=3e-3)
    assert sc.reflectance[sc.names.index("lamp")] == pytest.approx([0.7, 0.7, 0.7])


@pytest.mark.parametrize("parts, light, message", [
    ({"floor": (np.zeros((0, 3)), np.zeros((0, 3), np.int64))}, "x", "no faces"),
    ({"floor": (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.array([[0, 1, 2]]))}, "x",
     "part 'floor': face 0 is degenerate"),
    ({"floor": FLOOR, "lamp": LAMP}, "lampe", "light 'lampe' has no vertices and no mesh part"),
])
def test_bad_meshes_are_refused_by_name(tmp_path, parts, light, message):
    import trimesh

    if not len(parts["floor"][1]):
        trimesh.Trimesh(*parts["floor"], process=False).export(tmp_path / "m.ply")
        f = "m.ply"
    else:
        write_glb(tmp_path / "m.glb", parts)
        f = "m.glb"
    with pytest.raises(BadInput, match=message):
        parse_scene(mesh_doc([{"file": f, "material": "w"}], [{"name": light, "emittance": [1, 1, 1]}]),
                    base_dir=str(tmp_path))


def test_non_finite_vertex_names_the_face(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 4\nf 1 2 3\n")
    with pytest.raises(BadInput, match=r"vertex 2 is not finite \(face 1\)"):
        parse_scene(mesh_doc([{"file": "m.obj", "material": "w"}], [{"name": "m"}]),
                    base_dir=str(tmp_path))


def test_a_mesh_scene_without_lights_is_refused(tmp_path):
    write_glb(tmp_path / "m.glb", {"floor": FLOOR, "lamp": LAMP})
    with pytest.raises(BadInput, match=r"no light: .*\(mesh parts: .*floor"):
        parse_scene(mesh_doc([{"file": "m.glb", "material": "w"}], []), base_dir=str(tmp_path))


def test_cli_refuses_a_mesh_light_the_file_lacks_with_exit_2(tmp_path):
    import subprocess
    import sys

    write_glb(tmp_path / "m.glb", {"floor": FLOOR, "lamp": LAMP})
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(mesh_doc(
        [{"file": "m.glb", "material": "w"}], [{"name": "sun", "emittance": [1, 1, 1]}],
        photo="p.exr")))
    from nodes.io.images import encode_image

    (tmp_path / "p.exr").write_bytes(encode_image(np.ones((8, 8, 3), np.float32), ".exr", 16))
    (tmp_path / "g.yaml").write_text(
        "graphkit: 1\nnodes:\n  scene: {type: LoadScene, params: {path: s.yaml}}\n"
        "outputs: {cam: scene.camera}\n")
    r = subprocess.run([sys.executable, "-m", "graphkit", "run", "g.yaml", "--out", "out",
                        "--cache", "cache"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2, r.stderr
    assert "scene" in r.stderr and "light 'sun'" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# -- the builtin scenes as meshes -----------------------------------------------------------


@pytest.mark.parametrize("name", ["room", "cornell2", "cornell3"])
def test_builtin_mesh_scenes_are_the_same_polygons(name):
    """room / cornell3 (OBJ) and cornell2 (PLY per part) load back as the same polygons:
    equal areas, reflectances, emittances and lights (vertex order may differ)."""
    docs = [yaml.safe_load(open(os.path.join(DATA, f"{n}.yaml"))) for n in (name, name + "_mesh")]
    (a, ca, pa), (b, cb, pb) = (parse_scene(d, base_dir=DATA) for d in docs)
    assert pa == pb and ca == cb and a.light_names == b.light_names
    key = lambda s: sorted(zip(map(tuple, s.reflectance), map(tuple, s.emittance), s.light,  # noqa: E731
                               G.frame(s.verts)[4]))
    ka, kb = key(a), key(b)
    assert [k[:3] for k in ka] == [k[:3] for k in kb]
    assert [k[3] for k in ka] == pytest.approx([k[3] for k in kb], rel=1e-6)  # PLY: float32
    assert not G.is_triangle(b.verts).any()


def test_cornell3_from_its_mesh_file_relights_within_0_3_db():
    """builtin:cornell3 and builtin:cornell3_mesh, light A off, against the Mitsuba reference
    (data/cornell3_A_off.exr), at coarse settings: PSNRs within 0.3 dB."""
    from nodes.io.images import read_image
    from nodes.loscos.radiosity import RadiositySolve, TextureRefine
    from nodes.loscos.relight import Relight, Unocclude
    from nodes.loscos.scene import LoadScene
    from nodes.loscos.textures import ProjectTextures

    def run(node, params, **kw):
        return node(node.Params(**params), Context()).compute(**kw)

    ref = read_image(os.path.join(DATA, "cornell3_A_off.exr"))[0][..., :3]
    got = []
    for n in ("cornell3", "cornell3_mesh"):
        s = run(LoadScene, {"path": f"builtin:{n}"})
        pr = run(ProjectTextures, {"resolution": 32}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
        sol = run(RadiositySolve, COARSE, scene=s["scene"], projection=pr)["solution"]
        rf = run(TextureRefine, {"max_level": 3, "min_area": 0.02, "max_rounds": 1},
                 scene=s["scene"], solution=sol, projection=pr)
        un = run(Unocclude, {}, solution=rf, projection=pr, photo=s["photo"])["unoccluded"]
        light = s["scene"].light_names[0]
        img = run(Relight, {"light_scale": {light: 0.0}}, solution=rf, unoccluded=un,
                  projection=pr, photo=s["photo"]).pixels
        got.append(psnr(img, ref, pr.pix_poly >= 0))
    assert abs(got[0] - got[1]) <= 0.3, got
