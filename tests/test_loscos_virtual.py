"""Virtual objects you can move (Loscos 2000 §4.5, nodes/loscos/virtual.py) on the nodes' small
example room with a real box (embree.ray_examples, 718 leaves): the shaft test is conservative,
moving is the same as inserting at the new place (the links only the old bounds crossed go back),
removing gives the room back, a virtual light lights it, and bad places are refused by name."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from graphkit import BadInput, Context

BOX = dict(center=(0.4, -0.85, 0.2), size=(0.3, 0.3, 0.3), rotation_deg=20,
           reflectance=(0.8, 0.4, 0.1))


@functools.lru_cache(maxsize=1)
def room():
    from nodes.loscos.embree import ray_examples
    from nodes.loscos.relight import Unocclude

    e = ray_examples()
    un = Unocclude(Unocclude.Params(), Context()).compute(
        solution=e["refined"], projection=e["projection"], photo=e["photo"])["unoccluded"]
    return e, un


def session():
    from nodes.loscos.virtual import VirtualSession

    e, un = room()
    return VirtualSession(e["refined"], un, e["projection"], e["photo"].pixels[:, :, :3],
                          e["camera"], names=e["scene"].names)


def box(name="v", **kw):
    from nodes.loscos.virtual import box_thing

    return box_thing(name, **{**BOX, **kw})


def test_shaft_test_keeps_every_link_the_box_blocks():
    from nodes.loscos import virtual as VV

    S = session()
    t = box()
    h = S.h
    crossed = set(VV.shaft_crossed(S.bounds, t.lo, t.hi).tolist())
    p0, p1 = VV.link_rays(h, h.recv, h.send, 3)
    hit = VV.segments_hit(p0.reshape(-1, 3), p1.reshape(-1, 3), t.tris).reshape(len(h.recv), -1)
    blocked = set(np.flatnonzero(hit.any(1)).tolist())
    assert blocked and blocked <= crossed
    assert len(crossed) < 0.5 * len(h.recv)  # …and it is a real cut


def test_shaft_test_paths_agree_with_the_plain_test():
    """shaft_crossed's float32 thresholds and both of its paths (capsule on every link where
    most boxes overlap, on the overlapping ones' rows else) find what the plain test finds:
    float64 box comparisons, then the capsule on the links that pass."""
    from nodes.loscos import virtual as VV

    S = session()
    blo, bhi = S.bounds[0:3], S.bounds[3:6]
    rng = np.random.default_rng(5)
    big = 0
    for size in (0.02, 0.3, 3.0) * 6:
        c = rng.uniform(-1, 1, 3)
        g = size * rng.random(3)
        lo, hi = c - g, c + g * rng.random()
        ok = np.all((blo <= hi[:, None]) & (bhi >= lo[:, None]), 0)
        cand = np.flatnonzero(ok)
        m, r = (0.5 * (lo + hi)).astype(np.float32), 0.5 * np.linalg.norm(hi - lo)
        want = cand[VV._capsule_gap(m, S.bounds[6:, cand]) <= r]
        np.testing.assert_array_equal(VV.shaft_crossed(S.bounds, lo, hi), want)
        big += 2 * len(cand) > len(ok)
    assert 0 < big < 18  # both paths taken
    x = np.float64(np.float32(0.1)) + np.array([-1e-12, 0.0, 1e-12])  # at a float32 value
    f = np.float32(0.1)
    assert ((f <= VV._f32_at_most(x)) == (f <= x)).all() and ((f >= VV._f32_at_least(x)) == (f >= x)).all()


def test_near_leaves_left_out_receive_nothing():
    """The leaves _near_leaves leaves out (behind every vertex of the object) have all-zero
    kernel rows: the object's reflected light is the same without them."""
    from nodes.loscos import virtual as VV

    S = session()
    for t in (box(), box(center=(0.1, -0.9, -0.1), size=(0.6, 0.2, 0.4))):
        mid, r = 0.5 * (t.lo + t.hi), 0.5 * np.linalg.norm(t.hi - t.lo)
        every = np.flatnonzero(np.linalg.norm(S.leaf_c - mid, axis=1) < VV.NEAR * r)
        out = np.setdiff1d(every, S._near_leaves(t))
        assert len(out) and len(out) < len(every)
        F = VV._point_kernel(S.leaf_c[out], S.leaf_n[out], t.centre, t.normal, t.area)
        assert not F.any()


def test_union_of_link_runs_is_np_unique():
    from nodes.loscos import virtual as VV

    rng = np.random.default_rng(2)
    runs = [np.sort(rng.choice(500, k, replace=False)) for k in (40, 0, 90, 7)]
    idx, inv = VV._union(runs)
    want = np.unique(np.concatenate(runs), return_inverse=True)
    np.testing.assert_array_equal(idx, want[0])
    np.testing.assert_array_equal(inv, want[1])
    assert len(VV._union([])[0]) == 0


#: what stopping the update at TOL (relative to the brightest emittance) leaves, in radiance
#: (the image peaks at about 0.7)
SOLVER = 5e-3


def test_insert_move_remove_are_incremental_and_consistent():
    S = session()
    i0 = S.image()
    i1 = S.insert(box())
    assert S.stats["iterations"] < 20 and 0 < S.stats["links_reevaluated"] < len(S.h.recv)
    changed = np.abs(i1 - i0).max(2) > 0.02
    assert changed.sum() > 20  # the box and its shadow
    i2 = S.move("v", offset=(-0.25, 0, 0.15))
    # a step over REACH / 3: its links are found on the spot, with no reach around them
    assert S.stats["reach"] == "built"
    assert len(S.things["v"].reach.links) == S.stats["links_reevaluated"]
    fresh = session()
    fresh.insert(box(center=(0.15, -0.85, 0.35)))
    assert np.abs(i2 - fresh.image()).max() < SOLVER  # the old bounds' links went back
    assert np.abs(i2 - i1).max() > 0.1
    i3 = S.move("v", offset=(0.25, 0, -0.15))
    assert np.abs(i3 - i1).max() < SOLVER
    i4 = S.remove("v")
    assert np.abs(i4 - i0).max() < SOLVER


def test_a_drag_within_reach_finds_what_the_full_shaft_test_finds():
    """Small steps keep the links found once around the object (virtual.REACH): each step
    re-evaluates exactly the links the shaft test over all links finds, and the last step's
    links, their factors and the image are a fresh insert's at that place."""
    from nodes.loscos import virtual as VV

    S = session()
    S.insert(box())
    reach = S.things["v"].reach
    for _ in range(3):
        S.move("v", offset=(0.02, 0, -0.01))
        t = S.things["v"].thing
        assert S.things["v"].reach is reach
        assert S.stats["links_reevaluated"] == len(VV.shaft_crossed(S.bounds, t.lo - 1e-6, t.hi + 1e-6))
    fresh = session()
    fresh.insert(box(center=(0.46, -0.85, 0.17)))
    p, q = S.things["v"], fresh.things["v"]
    np.testing.assert_array_equal(p.links, q.links)
    np.testing.assert_allclose(p.vfac, q.vfac, atol=1e-9)
    assert np.abs(S.image() - fresh.image()).max() < SOLVER


def test_a_drag_builds_its_next_reach_ahead_and_it_is_a_full_build():
    """A drag builds the reach it will need next a slice of the links per move
    (VirtualSession._look_ahead) and switches to it when the object leaves the current one:
    that reach is the one built from scratch for its box (links, shaft bounds, rays, weights),
    and every move re-evaluates exactly the links the shaft test over all links finds."""
    from nodes.loscos import virtual as VV

    S = session()
    S.insert(box())
    kinds = []
    for _ in range(14):
        S.move("v", offset=(0.02, 0, -0.01))
        t = S.things["v"].thing
        kinds.append(S.stats["reach"])
        assert S.stats["links_reevaluated"] == len(VV.shaft_crossed(S.bounds, t.lo - 1e-6, t.hi + 1e-6))
    assert kinds.count("ahead") >= 2 and "built" not in kinds, kinds
    R = S.things["v"].reach
    full = S._reach(R.lo, R.hi, None)
    np.testing.assert_array_equal(R.links, full.links)
    for a, b in zip((*R.bounds, *R.pack[1:], R.w), (*full.bounds, *full.pack[1:], full.w)):
        np.testing.assert_array_equal(a, b)
    fresh = session()
    fresh.insert(box(center=(0.68, -0.85, 0.06)))
    p, q = S.things["v"], fresh.things["v"]
    np.testing.assert_array_equal(p.links, q.links)
    np.testing.assert_allclose(p.vfac, q.vfac, atol=1e-9)


def test_rays_left_out_by_the_box_test_miss():
    """packed_hit casts only the rays near_box keeps: every segment that crosses a triangle
    (here: through random points on a box's faces, some grazing an edge, some along an axis)
    is kept, and the answers are those of casting all of them."""
    from nodes.common import rays
    from nodes.loscos import virtual as VV

    rng = np.random.default_rng(3)
    tris = box().tris
    n = 4000
    f = rng.integers(0, len(tris), n)
    a, b = rng.random((2, n, 1))
    a, b = np.where(a + b > 1, 1 - a, a), np.where(a + b > 1, 1 - b, b)
    a[:200] = 0.0  # on an edge
    x = tris[f, 0] + a * (tris[f, 1] - tris[f, 0]) + b * (tris[f, 2] - tris[f, 0])
    d = rng.normal(size=(n, 3))
    d[:300, :2] = 0.0  # along an axis
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p0, p1 = x - rng.random((n, 1)) * d, x + rng.random((n, 1)) * d
    t = VV._triangle_t(p0, p1 - p0, tris)
    with np.errstate(invalid="ignore"):
        hit = ((t > rays.T_EPS) & (t < 1 - rays.T_EPS)).any(1)
    assert hit.sum() > 0.9 * n
    keep = VV.near_box(p0, p1 - p0, tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0))
    assert keep[hit].all()
    np.testing.assert_array_equal(VV.packed_hit(("numpy", p0, p1), tris), hit)
    assert not VV.near_box(p0 + 5.0, p1 - p0, tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)).any()


def test_virtual_light_and_a_mesh_file(tmp_path):
    import trimesh

    from nodes.loscos.virtual import light_thing, mesh_thing

    S = session()
    i0 = S.image()
    i1 = S.insert(light_thing("V", (-0.5, 0.9, 0.3), (0.3, 0.3), (0, -1, 0), (30.0, 30.0, 30.0)))
    lum = lambda im: im.mean()  # noqa: E731
    assert lum(i1) > 1.05 * lum(i0)
    path = tmp_path / "cone.obj"
    trimesh.creation.cone(0.15, 0.3, sections=12).export(path)
    i2 = S.insert(mesh_thing("cone", path, (0.4, -1.0, 0.2)), port="mesh")
    assert np.abs(i2 - i1).max(2).max() > 0.1
    i3 = S.move("cone", to=(0.1, -1.0, 0.3), port="mesh")
    assert np.abs(i3 - i2).max() > 0.1
    # the light keeps its form factors and its rays' real blockers: its V is still the one
    # cast from scratch against the real polygons and the cone where it is now
    from nodes.loscos.virtual import _light_quad

    V = S.things["V"]
    F, Vfull = S._point_to_polygons(S.leaf_c, S.leaf_n, *_light_quad(V.thing), np.full(1, -1))
    assert (Vfull[:, 0] < 1).sum() > 20
    np.testing.assert_array_equal(V.F, F[:, 0])
    np.testing.assert_array_equal(V.V, Vfull[:, 0])


@pytest.mark.parametrize("where,words", [
    (dict(center=(3.0, -0.85, 0.2)), "lies outside the room"),
    (dict(center=(-1.0, -0.5, 0.0)), "inside a wall: it crosses polygon 'left'"),
    (dict(center=(-0.2, -0.85, -0.05)), "inside a wall: it crosses polygon 'box."),
])
def test_bad_places_are_refused_by_name(where, words):
    S = session()
    with pytest.raises(BadInput) as e:
        S.insert(box("crate", **where))
    assert "virtual object 'crate'" in str(e.value) and words in str(e.value)
    assert not S.things
    i1 = S.insert(box("crate"))
    with pytest.raises(BadInput, match="virtual object 'crate' lies outside the room"):
        S.move("crate", offset=(5, 0, 0))
    assert np.array_equal(S.image(), i1)  # nothing changed


def test_relight_refuses_a_box_in_a_wall():
    from nodes.loscos.relight import Relight

    params, inputs = Relight.examples()[-1]
    bad = {**params["virtual_boxes"][0], "name": "crate", "center": [0.0, -0.85, -1.0]}
    node = Relight(Relight.Params(virtual_boxes=[bad]), Context())
    with pytest.raises(BadInput, match="virtual object 'crate' is inside a wall"):
        node.compute(**inputs)


def test_cli_box_in_a_wall_exits_2_naming_it(tmp_path):
    """graphkit run: exit 2, one message naming the node, the port and the object, no
    traceback, nothing in --out and no Relight result in the cache."""
    import subprocess
    import sys

    import yaml

    from nodes.io.images import encode_image
    from nodes.loscos.scene import example_doc, example_photo

    (tmp_path / "scene.yaml").write_text(yaml.safe_dump({**example_doc(), "photo": "photo.exr"}))
    (tmp_path / "photo.exr").write_bytes(encode_image(example_photo().pixels, ".exr", 32))
    (tmp_path / "g.yaml").write_text(
        "graphkit: 1\nnodes:\n"
        "  scene: {type: LoadScene, params: {path: scene.yaml}}\n"
        "  textures: {type: ProjectTextures, inputs: {scene: scene.scene, camera: scene.camera,"
        " photo: scene.photo}, params: {resolution: 8}}\n"
        "  radiosity: {type: RadiositySolve, inputs: {scene: scene.scene, projection:"
        " textures.projection}, params: {eps_bf: 0.5, eps_bfv: 0.05, min_area: 0.05, max_level: 3}}\n"
        "  unoccluded: {type: Unocclude, inputs: {solution: radiosity.solution, projection:"
        " textures.projection, photo: scene.photo}}\n"
        "  relit: {type: Relight, inputs: {solution: radiosity.solution, unoccluded:"
        " unoccluded.unoccluded, projection: textures.projection, photo: scene.photo, camera:"
        " scene.camera}, params: {virtual_boxes: [{name: crate, center: [0.0, -0.85, -1.0],"
        " size: [0.3, 0.3, 0.3]}]}}\n"
        "  save: {type: SaveImage, inputs: {image: relit.image}, params: {path: relit.exr}}\n"
        "outputs: {relit: save.file}\n")
    r = subprocess.run([sys.executable, "-m", "graphkit", "run", "g.yaml", "--out", "out",
                        "--cache", "cache"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    assert "relit" in r.stderr and "Relight" in r.stderr and "virtual_boxes" in r.stderr
    assert "virtual object 'crate' is inside a wall: it crosses the scene's polygon 0" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()
    cached = " ".join(p.read_text() for p in (tmp_path / "cache").rglob("*.json"))
    assert "Relight" not in cached and "SaveImage" not in cached


def test_a_drag_through_embree_blocks_what_numpy_blocks():
    """The Embree ray packs (float32 origins and directions, kept across a drag) find the
    links and V factors of the numpy reference, and the same image."""
    from nodes.common import rays

    S = session()
    S.insert(box())
    for _ in range(2):
        S.move("v", offset=(0.02, 0, -0.01))
    with rays.using("embree"):
        E = session()
        E.insert(box())
        for _ in range(2):
            E.move("v", offset=(0.02, 0, -0.01))
    p, q = S.things["v"], E.things["v"]
    assert q.reach.pack[0] == "embree" and p.reach.pack[0] == "numpy"
    np.testing.assert_array_equal(p.links, q.links)
    np.testing.assert_allclose(p.vfac, q.vfac, atol=1e-6)
    assert np.abs(S.image() - E.image()).max() < 1e-6
