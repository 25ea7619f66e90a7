"""Cluster links above the root polygons (issue 27 item 3; nodes/loscos/clusters.py): the
cluster refinement covers every ordered pair of distinct polygons exactly once, and a
clustered solve of a closed, furnished box meets the white furnace's analytic answer."""
from __future__ import annotations

import numpy as np

from nodes.common import rays
from nodes.loscos import clusters as CL
from nodes.loscos import geometry as G
from nodes.loscos import hierarchy as HR
from nodes.loscos import radiosity as R
from nodes.loscos.ports import RoomScene


def grid(o, u, v, n):
    """An n×n grid of the parallelogram (o, u, v) as 2n² triangles (a, b, c, c), normal u×v."""
    o, u, v = (np.asarray(x, float) for x in (o, u, v))
    out = []
    for i in range(n):
        for j in range(n):
            a = o + (i * u + j * v) / n
            b, c, d = a + u / n, a + (u + v) / n, a + v / n
            out += [[a, b, c, c], [a, c, d, d]]
    return out


def box(lo, size, n, inward):
    """The six faces of a cube (corner lo, side size) as grids, normals in- or outward."""
    lo = np.asarray(lo, float)
    e = np.eye(3) * size
    faces = []
    for k in range(3):
        u, v = e[(k + 1) % 3], e[(k + 2) % 3]  # u × v = +e_k
        faces += [(lo, v, u), (lo + e[k], u, v)]  # the −k face (normal −e_k), the +k face
    out = []
    for o, u, v in faces:
        out += grid(o, v, u, n) if inward else grid(o, u, v, n)
    return out


def furnished_box():
    """A 2 m closed box (inward, 8×8 cells a face) around a 0.6 m box (outward, 3×3) 0.4 m above the floor and a
    small lamp triangle under the ceiling, facing down: 876 + 1 triangles, past CLUSTER_ABOVE."""
    verts = box([0, 0, 0], 2.0, 8, True) + box([0.5, 0.4, 0.7], 0.6, 3, False)
    lamp = [[0.9, 1.99, 0.9], [1.1, 1.99, 0.9], [0.9, 1.99, 1.1], [0.9, 1.99, 1.1]]
    verts = np.array(verts + [lamp])
    P = len(verts)
    light = [""] * (P - 1) + ["lamp"]
    em = np.zeros((P, 3))
    em[-1] = 50.0
    return RoomScene([f"p{k}" for k in range(P)], verts, np.full((P, 3), 0.5), em, light)


def test_furnished_box_is_closed_and_past_the_cluster_threshold():
    sc = furnished_box()
    o, u, v, n, a = G.frame(sc.verts)
    assert len(sc.verts) > R.CLUSTER_ABOVE
    # closed: the outer box's area and its faces' normals sum to zero (each face pairs)
    assert abs(a[:768].sum() - 24.0) < 1e-9 and np.abs((n[:768] * a[:768, None]).sum(0)).max() < 1e-9
    assert np.all(n[:128] @ [1.0, 0, 0] > 0.99)  # the x = 0 wall faces inwards


def test_cluster_refinement_covers_every_ordered_pair_once():
    rng = np.random.default_rng(1)
    P = 300
    c = rng.uniform(0, 4, (P, 1, 3)) + rng.uniform(-0.05, 0.05, (P, 4, 3))
    B = rng.uniform(0.1, 1.0, P)
    light = np.zeros(P, bool)
    light[:3] = True
    t = CL.build_tree(c, np.full(P, 0.01), B, light)
    (r, s), (Rn, Sn) = CL.refine_clusters(t, 0.1, float(np.median(B)))
    assert len(Rn) > 0 and len(r) < P * (P - 1) / 2  # clusters took most of the pairs
    lr, pr = CL.members(t, Rn)
    ls, ps = CL.members(t, Sn)
    cnt = np.zeros((P, P), int)
    np.add.at(cnt, (r, s), 1)
    for k in range(len(Rn)):
        cnt[np.ix_(pr[lr == k], ps[ls == k])] += 1
    assert np.array_equal(cnt, 1 - np.eye(P, dtype=int))
    assert not np.isin(ps, np.flatnonzero(light)).any()  # lights send through polygon links


def test_clustered_white_furnace():
    """Every polygon of a closed box emitting E with reflectance ρ has B = E / (1 − ρ): the
    polygon and cluster links' form factors of each receiver must sum to one, the inner box
    must shade the walls behind it exactly as much as it replaces them, and a cluster must
    not light its back faces."""
    sc = furnished_box()
    prm = HR.RefineParams(eps_bf=0.3, eps_bfv=0.03, min_area=0.01, max_level=2, n_rays=4,
                          n_ff=3, seed=0, max_link_area=0.5)
    with rays.using("embree"):
        h = R.hierarchical_solve(sc, prm, rounds=1, tol=1e-6)
    assert len(h.cl_V) > 1000  # the transport is mostly in cluster links
    ops = HR.operators(h)
    L = len(ops.leaves)
    B, _ = HR.solve(ops, np.ones((L, 1)), np.full((L, 1), 0.5), tol=1e-8)
    a = h.area(ops.leaves)
    rel = B[:, 0] / 2.0 - 1  # measured: bias −0.2 %, mean |error| 2.1 %, max 11 %
    assert abs(np.sum(a * rel)) / a.sum() < 0.01
    assert np.sum(a * np.abs(rel)) / a.sum() < 0.03
    assert np.abs(rel).max() < 0.15


def test_reference_rays_over_many_occluders_test_only_the_near_ones_with_the_same_answers():
    """Past rays.MANY_OCCLUDERS the numpy reference groups segments and tests each group only
    against the occluders its box meets: the same answers as every segment against all."""
    rng = np.random.default_rng(3)
    P, N = 5000, 3000
    o = rng.uniform(0, 5, (P, 3))
    u, v = rng.normal(0, 0.1, (P, 3)), rng.normal(0, 0.1, (P, 3))
    n = np.cross(u, v)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    tri = rng.random(P) < 0.5
    p0 = rng.uniform(0, 5, (N, 3))
    p1 = p0 + rng.normal(0, 0.5, (N, 3))
    ignore = rng.integers(-1, P, (N, 2))
    assert P > rays.MANY_OCCLUDERS
    got = rays.occluded(p0, p1, (o, u, v, n, tri), ignore)
    full = rays._occluded_all(p0, p1, o, u, v, n, tri, ignore)
    assert 100 < full.sum() < N - 100
    assert np.array_equal(got, full)
    assert np.array_equal(rays._occluded_near(p0, p1, o, u, v, n, tri, ignore, group=3), full)


def ball_in_plain_box():
    """A 2 m closed box of six single quads (inward, 4 m² each) around an icosphere of 1,280
    triangles (radius 0.3 m, outward, 0.0009 m² each): past CLUSTER_ABOVE, every polygon
    emitting 1 W/m² with reflectance 0.5."""
    import trimesh

    quads = []
    e = np.eye(3) * 2.0
    for k in range(3):
        u, v = e[(k + 1) % 3], e[(k + 2) % 3]
        for o, a, b in ((np.zeros(3), u, v), (e[k], v, u)):  # normals +e_k at 0, −e_k at 2
            quads.append([o, o + a, o + a + b, o + b])
    ball = trimesh.creation.icosphere(3, 0.3)
    tri = ball.vertices[ball.faces] + 1.0
    verts = np.array(quads + [[a, b, c, c] for a, b, c in tri])
    P = len(verts)
    return RoomScene([f"p{k}" for k in range(P)], verts, np.full((P, 3), 0.5),
                     np.ones((P, 3)), [""] * P)


def test_small_polygons_do_not_split_a_big_partner_by_size_alone():
    """In a clustered scene a link whose smaller end is at most min_area (it cannot be split)
    is not split on the other end for max_link_area alone (BF still splits it): a mesh's
    small triangles would each get a link from every ≤ 0.5 m² piece of every wall.  Links
    between two large elements still are; the furnace still holds."""
    sc = ball_in_plain_box()
    o, u, v, n, a = G.frame(sc.verts)
    assert np.all(np.einsum("pc,pc->p", n[:6], 1.0 - o[:6] - 0.5 * (u[:6] + v[:6])) > 0)  # inward
    prm = HR.RefineParams(eps_bf=1.0, eps_bfv=1.0, min_area=0.01, max_level=2, n_rays=2,
                          n_ff=3, seed=0, max_link_area=0.5)
    with rays.using("embree"):
        h = R.hierarchical_solve(sc, prm, rounds=1, tol=1e-6)
    ar, as_ = h.area(h.recv), h.area(h.send)
    small = np.minimum(ar, as_) <= prm.min_area
    assert small.any() and (np.maximum(ar, as_)[small] > prm.max_link_area).any()
    assert np.all(np.maximum(ar, as_)[~small] <= prm.max_link_area)
    ops = HR.operators(h)
    L = len(ops.leaves)
    B, _ = HR.solve(ops, np.ones((L, 1)), np.full((L, 1), 0.5), tol=1e-8)
    w = h.area(ops.leaves)
    rel = B[:, 0] / 2.0 - 1
    assert abs(np.sum(w * rel)) / w.sum() < 0.01
    assert np.sum(w * np.abs(rel)) / w.sum() < 0.03
    assert np.abs(rel).max() < 0.15
