"""nodes/common/rays.py: the Embree occlusion backend against the numpy reference, on the
segments the Loscos solver casts (sender and receiver facing each other) in builtin:room, and
on the cases where float32 and the reference could part: segments that start on their own
polygon, graze it, or end on a neighbour.  The node-level agreement (``--backend embree``) is
tests/test_conformance.py, on the nodes' examples (nodes/loscos/embree.py)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import Context
from nodes.common import rays
from nodes.loscos import geometry as G
from nodes.loscos.scene import LoadScene

pytest.importorskip("embreex", reason="embreex is a dependency (pyproject.toml)")


def _room_occluders():
    sc = LoadScene(LoadScene.Params(path="builtin:room"), Context()).compute()["scene"]
    po, pu, pv, pn, _ = G.frame(sc.verts)
    return po, pu, pv, pn


def _facing_segments(occ, n, seed):
    po, pu, pv, pn = occ
    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, len(po), (2, n))
    sa, sb = rng.random((2, n, 2))
    p0 = po[a] + sa[:, :1] * pu[a] + sa[:, 1:] * pv[a]
    p1 = po[b] + sb[:, :1] * pu[b] + sb[:, 1:] * pv[b]
    d = p1 - p0
    f = (np.einsum("nc,nc->n", d, pn[a]) > 1e-9) & (np.einsum("nc,nc->n", -d, pn[b]) > 1e-9)
    return p0[f], p1[f], np.stack([a, b], 1)[f]


def test_embree_agrees_with_reference_on_room_links():
    occ = _room_occluders()
    p0, p1, ign = _facing_segments(occ, 60_000, seed=3)
    ref = rays.occluded(p0, p1, occ, ign)
    with rays.using("embree"):
        got = rays.occluded(p0, p1, occ, ign)
    assert len(p0) > 10_000 and 0.1 < ref.mean() < 0.9  # both answers are common
    assert (got != ref).sum() <= len(p0) // 500, f"{(got != ref).sum()} of {len(p0)} segments differ"


def test_reference_answers_alike_in_any_block_size():
    """The reference takes its blocks by segment–occluder pairs (so 20k mesh polygons do not
    make a block of segments hold gigabytes): blocks of one, 22 and all segments agree."""
    occ = _room_occluders()
    p0, p1, ign = _facing_segments(occ, 3000, seed=5)
    want = rays._occluded_numpy(p0, p1, *occ, ignore=ign, chunk=1 << 30)
    for chunk in (1, 1000):
        assert np.array_equal(rays._occluded_numpy(p0, p1, *occ, ignore=ign, chunk=chunk), want)
    assert 0.1 < want.mean() < 0.9


def test_own_polygons_ignored_and_end_points_excluded():
    # a floor (0) and a wall (1) meeting at an edge, and a blocker (2) between them
    o = np.array([[0, 0, 0], [0, 0, 0], [0.5, 0.0, -1.0]], float)
    u = np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]], float)
    v = np.array([[0, 0, 1], [0, 1, 0], [0, 0, 3]], float)
    n = np.cross(u, v)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    occ = (o, u, v, n)
    p0 = np.array([[0.9, 0, 0.5],        # floor → wall, crosses the blocker
                   [0.3, 0, 0.5],        # floor → wall, blocker behind the start
                   [0.4, 0, 0.5],        # grazing its own floor: 1e-7 above it at the far end
                   [0.2, 0, 0.5]])       # floor → blocker's own face (end point on it)
    p1 = np.array([[0, 0.5, 0.5], [0, 0.5, 0.5], [0.1, 1e-7, 0.5], [0.5, 0.3, 0.5]])
    ign = np.array([[0, 1], [0, 1], [0, -1], [0, 2]])
    want = np.array([True, False, False, False])
    assert np.array_equal(rays.occluded(p0, p1, occ, ign), want)
    with rays.using("embree"):
        assert np.array_equal(rays.occluded(p0, p1, occ, ign), want)


def test_scene_built_once_per_occluder_set():
    occ = _room_occluders()
    assert rays.scene(occ) is rays.scene(tuple(a.copy() for a in occ))
    moved = (occ[0] + 0.01,) + occ[1:]
    assert rays.scene(moved) is not rays.scene(occ)


def test_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="unknown ray-casting backend 'optix'"):
        with rays.using("optix"):
            pass


def test_boxes_meet_is_the_box_test_less_the_ignored_occluders():
    occ = _room_occluders()
    o, u, v = occ[:3]
    rng = np.random.default_rng(3)
    n = 3000
    c = np.stack([o, o + u, o + u + v, o + v], 1)
    lo = rng.uniform(c.min((0, 1)), c.max((0, 1)), (n, 3))
    hi = lo + rng.uniform(0, 0.4, (n, 3)) * (c.max((0, 1)) - c.min((0, 1)))
    ignore = rng.integers(-1, len(o), (n, 2))
    ignore[::7, 1] = ignore[::7, 0]  # the same occluder twice
    meet = ((lo[:, None] <= c.max(1)[None]) & (hi[:, None] >= c.min(1)[None])).all(2)
    want = (meet & (np.arange(len(o))[None] != ignore[:, :1])
            & (np.arange(len(o))[None] != ignore[:, 1:])).any(1)
    assert 0.2 < want.mean() < 0.98 and (meet.any(1) & ~want).any()
    assert np.array_equal(rays.boxes_meet(lo, hi, occ, ignore, chunk=1000), want)
    assert np.array_equal(rays.boxes_meet(lo, hi, occ), meet.any(1))


def test_link_visibility_and_point_form_factors_are_the_same_on_one_or_two_cores(monkeypatch):
    # link_visibility draws each block's random numbers in the caller, in block order, and
    # the blocks run on the cores (nodes.common.parallel.run_tasks): the bits must not
    # depend on the threads; nor ff_point_polygon's chunks
    import os

    from nodes.loscos import hierarchy as HR

    sc = LoadScene(LoadScene.Params(path="builtin:room"), Context()).compute()["scene"]
    h = HR.Hierarchy.roots(sc.verts)
    r, s = np.nonzero(~np.eye(len(sc.verts), dtype=bool))
    monkeypatch.setattr(HR, "RAYS_AT_ONCE", 16 * 97)  # many blocks of 97 links
    pts = G.corners(*h.geom(r)[:3])[:, 0] * 0.9 + 0.1 * G.corners(*h.geom(s)[:3])[:, 1]
    got = {}
    for cores in (1, 2):
        monkeypatch.setattr(os, "cpu_count", lambda cores=cores: cores)
        with rays.using("embree"):
            V, C = HR.link_visibility(h, r, s, 4, np.random.default_rng(5), centroid=True)
        F = G.ff_point_polygon(pts, h.geom(r)[3], G.corners(*h.geom(s)[:3]), chunk=101)
        got[cores] = V, C, F
    assert len(r) > 10 * 97 and 0.05 < (got[1][0] < 1).mean() < 0.95
    for a, b in zip(got[1], got[2]):
        assert np.array_equal(a, b)
    # each block cast in pieces of RAYS_IN_CACHE rays: the same bits as in one piece
    monkeypatch.setattr(HR, "RAYS_IN_CACHE", 16 * 13)
    with rays.using("embree"):
        V, C = HR.link_visibility(h, r, s, 4, np.random.default_rng(5), centroid=True)
    assert np.array_equal(V, got[2][0]) and np.array_equal(C, got[2][1])


def test_gather_in_row_bands_is_the_product_on_one_or_two_cores(monkeypatch):
    # Operators.gather multiplies K (Ku) in row bands on the cores (bands_matmul): every row
    # summed as scipy's one product sums it
    import os

    from nodes.loscos import hierarchy as HR

    sc = LoadScene(LoadScene.Params(path="builtin:room"), Context()).compute()["scene"]
    h = HR.Hierarchy.roots(sc.verts)
    h.subdivide(np.arange(len(sc.verts)))
    rng = np.random.default_rng(3)
    h.recv, h.send = rng.integers(0, h.n_elems, (2, 5000))
    h.F, h.V, h.C = rng.random(5000), rng.random(5000), rng.random((5000, 4))
    B = rng.random((len(h.leaves), 6))
    monkeypatch.setattr(HR, "BANDS_FROM", 100)
    got = {}
    for cores in (1, 2, 3):
        monkeypatch.setattr(os, "cpu_count", lambda cores=cores: cores)
        ops = HR.operators(h)
        assert len(ops.bands[False]) == cores
        got[cores] = ops.gather(B), ops.gather(B, unoccluded=True)
    want = ops.push @ (ops.K @ (ops.pull @ B)), ops.push @ (ops.Ku @ (ops.pull @ B))
    for cores in (1, 2, 3):
        assert all(np.array_equal(a, b) for a, b in zip(got[cores], want))


def test_embree_agrees_with_reference_between_touching_triangles():
    """builtin:room split into triangles (each pair touching along its diagonal, the walls
    meeting at edges): segments between random points of facing triangles, near-end hits and
    own re-hits included, answer as the reference does — all of them on an AVX-512 machine; on an
    AVX2 one embree's other kernels round 10 of the 12 508 (segments grazing a shared edge) the
    other way, so up to 1 in 500 (25) may differ (embree given no own-triangle mask: 73)."""
    sc = LoadScene(LoadScene.Params(path="builtin:room"), Context()).compute()["scene"]
    v = sc.verts
    tris = np.concatenate([v[:, [0, 1, 2, 2]], v[:, [0, 2, 3, 3]]])
    po, pu, pv, pn, _ = G.frame(tris)
    p0, p1, ign = _facing_segments((po, pu, pv, pn), 60_000, seed=7)
    occ = (po, pu, pv, pn, np.ones(len(po), bool))
    inside = lambda s: s.sum(1) <= 1  # noqa: E731  (keep the points on the triangles)
    rng = np.random.default_rng(7)
    st0, st1 = rng.random((2, len(p0), 2)) * 0.999
    st0[~inside(st0)] = 1 - st0[~inside(st0)]
    st1[~inside(st1)] = 1 - st1[~inside(st1)]
    a, b = ign[:, 0], ign[:, 1]
    p0 = po[a] + st0[:, :1] * pu[a] + st0[:, 1:] * pv[a]
    p1 = po[b] + st1[:, :1] * pu[b] + st1[:, 1:] * pv[b]
    ref = rays.occluded(p0, p1, occ, ign)
    with rays.using("embree"):
        got = rays.occluded(p0, p1, occ, ign)
    assert 0.05 < ref.mean() < 0.95
    assert (got != ref).sum() <= len(p0) // 500, f"{(got != ref).sum()} of {len(p0)} segments differ"
