"""Virtual objects you can move, and virtual lights, after the preprocess (Loscos 2000 §4.5, §5).

:class:`VirtualSession` keeps what a preprocess gives (the solution's links and gather operator,
the pixel plan of the photograph) and inserts, moves and removes virtual things incrementally:

* a virtual **object** (a box, or any triangle mesh through trimesh) is a set of *patches*
  (a box face split into ``BOX_SPLIT``² parallelograms, or a mesh's triangles), each one leaf of
  its own beside the hierarchy's;
* the real links whose **shaft** the object's bounds cross (a conservative test: the links'
  bounding boxes against the object's, then the capsule around the two elements' centres) get
  their attenuation re-evaluated: rays between the two elements (``LINK_RAYS``² stratified
  pairs, kernel-weighted as in :func:`hierarchy.link_visibility`) cast against the object's
  triangles, V = V_preprocess × V_object (the object blocks the unblocked share);
* in a clustered room (past radiosity.CLUSTER_ABOVE polygons) the cluster links whose shafts
  (their members' bounds) the object's bounds cross get their receiver members' weights scaled
  by the share of LINK_RAYS² rays the object leaves unblocked (:class:`ClusterRays`), and the
  object gathers from a small far polygon as from a point (FAR);
* the object's patches gather from every real polygon and virtual light (point-to-polygon form
  factors from each patch's centre, visibility by rays through :func:`nodes.common.rays.occluded`
  against the real polygons and against every virtual triangle), and give back to the real
  leaves near them (the point kernel, reciprocity);
* radiosity is updated, not solved anew: B = E + ρ·gather(B) with the gather operator K₀ + ΔK
  (ΔK: only the changed links), iterated from the last B; the photograph's leaves are scaled by
  B / B_ref (B_ref: the same iteration without ΔK, once per session), as Relight does (§4.4);
* a virtual **light** is one emitting parallelogram linked to every real leaf and patch.

Moving an object re-evaluates the links crossed by its old or new bounds, its own links, and
the virtual lights' links to the leaves whose shafts it crossed.  The links are sought among
the object's *reach* (those its bounds grown by REACH cross); a drag builds the next reach
ahead of the object, a slice of all links per move, so no move scans them all.  The image is the pixel plan
applied to the new leaf multipliers, with the virtual things drawn over it by coverage
(``SUB``² rays per pixel in their screen box, depth-tested against the room).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from graphkit import BadInput

from . import geometry as G
from . import hierarchy as HR
from .relight import LUM, box_quads, emitter_leaves, fixture_glow, leaf_multiplier, quad_from

BOX_SPLIT = 4  # a box face → 4×4 patches
LINK_RAYS = 2  # 2×2 rays per re-evaluated real link (3×3: the same PSNR against Mitsuba, 1.5× the time)
SOURCE_RAYS = 3  # 3×3 points on each sender polygon seen from a patch / leaf
FAR = 0.25  # a clustered room's polygon below FAR × its distance from a patch is a point there
SUB = 3  # 3×3 coverage rays per pixel for drawing virtual things
NEAR = 3.0  # real leaves within NEAR × the object's radius receive its reflected light
TOL = 1e-4  # relative change of B at which the update stops
MAX_ITER = 60
EDGE = 1e-6  # placement: polygons shrink by this fraction, so touching is not crossing
REACH = 0.1  # m: a moved object's links are sought among those its bounds grown by this cross
SCAN_ALIGN = 4096  # the look-ahead scans the links in slices of multiples of this


# ------------------------------------------------------------------------------------------
# geometry of virtual things


def quad_patches(quads: np.ndarray, n: int):
    """Split parallelograms (K,4,3) into n×n: centres, normals, areas (K·n², …) and the
    parallelograms (o, u, v) of the patches."""
    o, u, v, nrm, area = G.frame(quads)
    g = np.arange(n)
    I, J = np.meshgrid(g, g, indexing="ij")
    po = o[:, None] + (I.ravel()[None, :, None] * u[:, None] + J.ravel()[None, :, None] * v[:, None]) / n
    pu = np.repeat(u / n, n * n, axis=0)
    pv = np.repeat(v / n, n * n, axis=0)
    po = po.reshape(-1, 3)
    return po + 0.5 * (pu + pv), np.repeat(nrm, n * n, 0), np.repeat(area / (n * n), n * n), (po, pu, pv)


def quad_triangles(quads: np.ndarray) -> np.ndarray:
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


@dataclass(eq=False)
class Thing:
    """A virtual object or light: its triangles (T,3,3) (occluders, drawn), patches (centre,
    normal, area, reflectance (n,3), emittance (n,3)) and, for drawing, each triangle's patch
    (a box face's triangles map their points to the face's n×n patches)."""

    name: str
    tris: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    rho: np.ndarray
    emit: np.ndarray
    light: bool = False
    #: per triangle: (patch of its first cell, split n, quad origin, u, v) for box faces; else
    #: patch = triangle index
    faces: tuple | None = None
    quads: np.ndarray | None = None

    @property
    def lo(self):
        return self.tris.reshape(-1, 3).min(0)

    @property
    def hi(self):
        return self.tris.reshape(-1, 3).max(0)

    @property
    def foot(self):
        """The centre of its bounding box's bottom (what a drag puts on the floor)."""
        lo, hi = self.lo, self.hi
        return np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])

    def moved(self, offset, rotation_deg: float = 0.0) -> "Thing":
        """The thing translated by ``offset`` and turned about +y (through its centre)."""
        c = np.radians(rotation_deg)
        R = np.array([[np.cos(c), 0, np.sin(c)], [0, 1, 0], [-np.sin(c), 0, np.cos(c)]])
        mid = 0.5 * (self.lo + self.hi)
        f = lambda x: (x - mid) @ R.T + mid + np.asarray(offset, float)  # noqa: E731
        q = None if self.quads is None else f(self.quads)
        return Thing(self.name, f(self.tris), f(self.centre), self.normal @ R.T, self.area,
                     self.rho, self.emit, self.light, self.faces, q)


def box_thing(name, center, size, rotation_deg=0.0, reflectance=(0.8, 0.45, 0.1)) -> Thing:
    """A diffuse box (as Relight's VirtualBox) split into patches."""
    quads = np.asarray(box_quads(center, size, rotation_deg), float)
    return _quad_thing(name, quads, BOX_SPLIT, np.asarray(reflectance, float), np.zeros(3))


def light_thing(name, center, size, normal, emittance) -> Thing:
    """A virtual rectangular area light (as Relight's VirtualLight): one emitting patch."""
    quads = quad_from(center, size, normal)[None]
    return _quad_thing(name, quads, 1, np.zeros(3), np.asarray(emittance, float), light=True)


def _quad_thing(name, quads, n, rho, emit, light=False) -> Thing:
    c, nrm, a, _ = quad_patches(quads, n)
    k = len(c)
    return Thing(name, quad_triangles(quads), c, nrm, a, np.tile(rho, (k, 1)),
                 np.tile(emit, (k, 1)), light, faces=(n,), quads=quads)


def mesh_thing(name, path, center, scale=1.0, rotation_deg=0.0,
               reflectance=(0.8, 0.45, 0.1), max_faces: int = 4000) -> Thing:
    """Any mesh file trimesh reads (OBJ, PLY, glTF/GLB, STL…), its bounding box's bottom centre
    put at ``center``: one patch per triangle."""
    import trimesh

    try:
        m = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise BadInput("mesh", f"virtual object '{name}': cannot read {path}: {e}") from None
    if len(m.faces) == 0:
        raise BadInput("mesh", f"virtual object '{name}': {path} has no faces")
    if len(m.faces) > max_faces:
        raise BadInput("mesh", f"virtual object '{name}': {len(m.faces)} faces, at most "
                               f"{max_faces} (decimate it first)")
    tris = np.asarray(m.triangles, float) * float(scale)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    tris = tris - np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    if not np.all(np.isfinite(tris)):
        raise BadInput("mesh", f"virtual object '{name}': non-finite vertices in {path}")
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    cr = np.cross(e1, e2)
    a = 0.5 * np.linalg.norm(cr, axis=1)
    ok = a > 1e-12
    tris, cr, a = tris[ok], cr[ok], a[ok]
    k = len(tris)
    t = Thing(name, tris, tris.mean(1), cr / (2 * a[:, None]), a,
              np.tile(np.asarray(reflectance, float), (k, 1)), np.zeros((k, 3)))
    return t.moved(np.asarray(center, float), rotation_deg)


# ------------------------------------------------------------------------------------------
# rays against triangles, and the shaft test


def segments_hit(p0: np.ndarray, p1: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Whether each open segment p0→p1 (N,3) crosses one of the triangles (T,3,3) (two-sided,
    t ∈ (T_EPS, 1 − T_EPS) as :func:`nodes.common.rays.occluded`); Embree when that backend is
    selected, else numpy (Möller–Trumbore)."""
    return packed_hit(ray_pack(p0, p1), tris)


def ray_pack(p0: np.ndarray, p1: np.ndarray) -> tuple:
    """Segments (N,3) as :func:`packed_hit` casts them: Embree's float32 origins (moved T_EPS
    along) and directions, or numpy's end points.  A drag keeps the packs of its links."""
    from nodes.common import rays

    if _ray_kind() == "numpy":
        return ("numpy", p0, p1)
    d = p1 - p0
    return ("embree", (p0 + rays.T_EPS * d).astype(np.float32), d.astype(np.float32))


def _ray_kind() -> str:
    from nodes.common import rays

    return "embree" if rays.backend() == "embree" else "numpy"


def packed_hit(pack: tuple, tris: np.ndarray) -> np.ndarray:
    """Whether each ray of a :func:`ray_pack` crosses one of the triangles (T,3,3): only the
    rays that may meet the triangles' bounding box are cast (a ray's answer does not depend on
    the others cast with it)."""
    from nodes.common import rays

    kind, p0, p1 = pack
    out = np.zeros(len(p0), bool)
    if len(p0) == 0 or len(tris) == 0:
        return out
    v = tris.reshape(-1, 3)
    m = np.flatnonzero(near_box(p0, p1 if kind == "embree" else p1 - p0, v.min(0), v.max(0)))
    p0, p1 = np.take(p0, m, axis=0), np.take(p1, m, axis=0)  # (take: ~4× fancy indexing)
    if kind == "embree":
        from embreex import mesh_construction, rtcore_scene

        sc = rtcore_scene.EmbreeScene(robust=True)
        mesh_construction.TriangleMesh(sc, tris.astype(np.float32))
        tfar = np.full(len(p0), 1 - 2 * rays.T_EPS, np.float32)
        out[m] = sc.run(p0, p1, dists=tfar, query="OCCLUDED") >= 0
        return out
    step = max(1, 2_000_000 // len(tris))
    for s in range(0, len(p0), step):
        o, d = p0[s:s + step], p1[s:s + step] - p0[s:s + step]
        t = _triangle_t(o, d, tris)
        out[m[s:s + step]] = ((t > rays.T_EPS) & (t < 1 - rays.T_EPS)).any(1)
    return out


def near_box(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether each segment o + t·d, t ∈ [0, 1] (N,3) may meet the box [lo, hi] (a slab test
    in the segments' precision, the box grown by 1 mm and 1e-4 of its size: conservative)."""
    g = 1e-3 + 1e-4 * float(np.max(hi - lo))
    lo, hi = (np.asarray(lo) - g).astype(o.dtype), (np.asarray(hi) + g).astype(o.dtype)
    t_in, t_out = np.zeros(len(o), o.dtype), np.ones(len(o), o.dtype)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for j in range(3):  # (0·∞ = NaN where o is on a face: fmin/fmax ignore it)
            inv = 1 / d[:, j]
            t1, t2 = (lo[j] - o[:, j]) * inv, (hi[j] - o[:, j]) * inv
            t_in = np.fmax(t_in, np.fmin(t1, t2))
            t_out = np.fmin(t_out, np.fmax(t1, t2))
    return t_in <= t_out


def _triangle_t(o: np.ndarray, d: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(N, T) ray parameter t where rays o + t·d meet triangles ``tris`` (T, 3, 3), two-sided
    (Möller–Trumbore); NaN where a ray misses a triangle or runs parallel to it."""
    a, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    pv = np.cross(d[:, None], e2[None])
    det = np.einsum("ntc,tc->nt", pv, e1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / det
        tv = o[:, None] - a[None]
        u = np.einsum("ntc,ntc->nt", tv, pv) * inv
        qv = np.cross(tv, e1[None])
        v = np.einsum("ntc,nc->nt", qv, d) * inv
        t = np.einsum("ntc,tc->nt", qv, e2) * inv
        ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1)
    return np.where(ok, t, np.nan)


def link_bounds(h: HR.Hierarchy) -> np.ndarray:
    """Per link what the shaft tests need, once per session (float32, half the memory traffic;
    (16, M), one row per quantity, see :func:`capsule_bounds`): the bounding box of both
    elements, and the tapered capsule
    around their bounding spheres (c₁, r₁), (c₂, r₂): c₁, the unit axis, its length L, the
    radius growth per metre k and the slope where the nearest point of the capsule leaves the
    axis (k/√(1−k²), k clipped below 1: |k| ≥ 1 is monotone, the clip reaches an end)."""
    o1, u1, v1, _, _ = h.geom(h.recv)
    o2, u2, v2, _, _ = h.geom(h.send)
    pts = np.concatenate([G.corners(o1, u1, v1), G.corners(o2, u2, v2)], axis=1)
    r1 = 0.5 * np.linalg.norm(u1 + v1, axis=1) + 1e-5  # (+ float32's rounding, to stay safe)
    r2 = 0.5 * np.linalg.norm(u2 + v2, axis=1) + 1e-5
    c1, c2 = o1 + 0.5 * (u1 + v1), o2 + 0.5 * (u2 + v2)
    return capsule_bounds(pts.min(1), pts.max(1), c1, r1, c2, r2)


def capsule_bounds(lo, hi, c1, r1, c2, r2) -> np.ndarray:
    """:func:`link_bounds`'s rows from each link's box (lo, hi: (M, 3)) and its two ends'
    bounding spheres (c₁, r₁), (c₂, r₂): lo (rows 0–2), hi (3–5), c₁ (6–8), the unit axis
    (9–11), L, r₁, k, slope (12–15), float32, each link a column (a link's rows are one
    gather, each quantity's values contiguous)."""
    L = np.maximum(np.linalg.norm(c2 - c1, axis=1), 1e-12)
    k = (r2 - r1) / L
    kc = np.clip(k, -0.999999, 0.999999)
    return np.ascontiguousarray(np.vstack([lo.T, hi.T, c1.T, ((c2 - c1) / L[:, None]).T, L, r1,
                                           k, kc / np.sqrt(1 - kc * kc)]), np.float32)


def shaft_crossed(bounds, lo, hi) -> np.ndarray:
    """Indices of links whose shaft (the convex hull of the two elements) may meet the box
    [lo, hi]: their bounding boxes overlap, and the box's bounding sphere (m, r) meets the
    tapered capsule around the elements' bounding spheres (c₁, r₁), (c₂, r₂) — which holds
    the hull: min over λ ∈ [0, L] of |m − c(λ)| − r(λ) ≤ r, c and r linear in λ (a convex
    function of λ, minimised in closed form).  The capsule is measured on every link where
    most boxes overlap (a reach's links: no gathers), else on those that do."""
    blo, bhi = bounds[0:3], bounds[3:6]
    below, above = _f32_at_most(hi), _f32_at_least(lo)  # (float32 thresholds, the same tests)
    ok = (blo[0] <= below[0]) & (bhi[0] >= above[0])
    for j in (1, 2):
        ok &= (blo[j] <= below[j]) & (bhi[j] >= above[j])
    m, r = (0.5 * (lo + hi)).astype(np.float32), 0.5 * np.linalg.norm(hi - lo)
    cand = np.flatnonzero(ok)
    if 2 * len(cand) > len(ok):
        return np.flatnonzero(ok & (_capsule_gap(m, bounds[6:]) <= r))
    return cand[_capsule_gap(m, np.take(bounds[6:], cand, axis=1)) <= r]


def _capsule_gap(m, cap: np.ndarray) -> np.ndarray:
    """|m − c(λ)| − r(λ) at its minimum over the capsule's axis (see :func:`shaft_crossed`);
    ``cap``: :func:`capsule_bounds`' rows 6–15."""
    w0, w1, w2 = m[0] - cap[0], m[1] - cap[1], m[2] - cap[2]
    a = w0 * cap[3] + w1 * cap[4] + w2 * cap[5]  # along the axis
    hh = np.sqrt(np.maximum(w0 * w0 + w1 * w1 + w2 * w2 - a * a, 0.0))  # off the axis
    s = np.clip(a + cap[9] * hh, 0, cap[6])
    return np.sqrt((a - s) ** 2 + hh * hh) - cap[7] - cap[8] * s


def _f32_at_most(x) -> np.ndarray:
    """The largest float32 values ≤ x (float64): ``y <= x`` ⇔ ``y <= this`` for float32 y."""
    y = np.asarray(x).astype(np.float32)
    return np.where(y > x, np.nextafter(y, np.float32(-np.inf)), y)


def _f32_at_least(x) -> np.ndarray:
    """The smallest float32 values ≥ x (float64)."""
    y = np.asarray(x).astype(np.float32)
    return np.where(y < x, np.nextafter(y, np.float32(np.inf)), y)


def link_rays(h: HR.Hierarchy, r, s, n: int):
    """Stratified ray end points (M, n², 3) on receivers r and senders s (each receiver point
    paired with a different sender point)."""
    return element_points(h, r, n), element_points(h, s, n, reverse=True)


def element_points(h: HR.Hierarchy, e, n: int, reverse: bool = False) -> np.ndarray:
    """(len(e), n², 3) stratified points on elements e, a link's receiver end (``reverse``:
    its sender end, in the opposite order); each element's points do not depend on e, so a
    session computes them for every element once and gathers."""
    st = G.grid_st(n)[::-1] if reverse else G.grid_st(n)
    o, u, v, _, _ = h.geom(e)
    return o[:, None] + st[None, :, 0:1] * u[:, None] + st[None, :, 1:2] * v[:, None]


def ray_weights(h: HR.Hierarchy, r, s, p0, p1):
    """The point-to-point kernel cos·cos/r⁴ of each ray (as hierarchy.link_visibility)."""
    rn, sn = h.P_n[h.poly[r]], h.P_n[h.poly[s]]
    d = p1 - p0
    r2 = np.maximum(np.einsum("mkc,mkc->mk", d, d), 1e-12)
    return (np.clip(np.einsum("mkc,mc->mk", d, rn), 0, None)
            * np.clip(-np.einsum("mkc,mc->mk", d, sn), 0, None) / (r2 * r2))


def weighted_visible(blocked: np.ndarray, w: np.ndarray) -> np.ndarray:
    vis = 1.0 - blocked
    ws = w.sum(1)
    return np.where(ws > 0, (w * vis).sum(1) / np.maximum(ws, 1e-300), vis.mean(1))


# ------------------------------------------------------------------------------------------
# a clustered room's cluster links (clusters.py)


@dataclass(eq=False)
class ClusterRays:
    """What blocking a clustered room's cluster links needs, once per session.  A cluster link
    R ← S is a rank-one block: receiver member p takes V/π · a_p · Σ_q b_q B_q.  An object
    multiplies a_p by the share of p's rays it leaves unblocked: LINK_RAYS² rays from
    stratified points on p (``pts``) to the centroids (``cent``) of sender members ``q`` drawn
    by their weights b_q (per receiver entry (link, p), fixed for the session).  ``bounds``:
    per link, its shaft's (:func:`capsule_bounds`: the box of all its members, the capsule
    around its receiver members' and its sender members' bounding spheres); ``start``: link l's
    receiver entries are ``start[l]:start[l + 1]``."""

    bounds: np.ndarray
    start: np.ndarray
    pts: np.ndarray
    cent: np.ndarray
    q: np.ndarray

    def factor(self, cl, tris: np.ndarray):
        """The receiver entries (into cl.r) whose rays the triangles block, and the unblocked
        share of each one's rays, for the links whose shafts the triangles' bounds cross."""
        v = tris.reshape(-1, 3)
        links = shaft_crossed(self.bounds, v.min(0), v.max(0))
        n = self.start[links + 1] - self.start[links]
        e = np.repeat(self.start[links], n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        q = self.q[e]
        p0 = np.broadcast_to(self.pts[cl.r[e, 1]], (len(e), *self.pts.shape[1:]))
        b = segments_hit(p0.reshape(-1, 3), self.cent[np.maximum(q, 0)].reshape(-1, 3), tris)
        vf = 1.0 - (b.reshape(q.shape) & (q >= 0)).mean(1)
        keep = vf < 1.0
        return e[keep], vf[keep]


def cluster_rays(h: HR.Hierarchy, rng) -> ClusterRays | None:
    """:class:`ClusterRays` of h's cluster links (None where links start at polygons)."""
    from .clusters import draw_entries

    cl = h.cluster_links()
    if not len(cl.V):
        return None
    M, tri = len(cl.V), h.tri_poly
    c = G.corners(h.P_o, h.P_u, h.P_v, tri)

    def box(ent):  # each link's members' box (entries sorted by link, every link has some)
        at = np.searchsorted(ent[:, 0], np.arange(M))
        return np.minimum.reduceat(c[ent[:, 1]].min(1), at), np.maximum.reduceat(c[ent[:, 1]].max(1), at)

    (lo1, hi1), (lo2, hi2) = box(cl.r), box(cl.s)
    bounds = capsule_bounds(np.minimum(lo1, lo2), np.maximum(hi1, hi2), 0.5 * (lo1 + hi1),
                            0.5 * np.linalg.norm(hi1 - lo1, axis=1) + 1e-5, 0.5 * (lo2 + hi2),
                            0.5 * np.linalg.norm(hi2 - lo2, axis=1) + 1e-5)
    k = LINK_RAYS * LINK_RAYS
    st = G.fold(np.broadcast_to(G.grid_st(LINK_RAYS), (len(tri), k, 2)), tri[:, None])
    pts = h.P_o[:, None] + st[..., :1] * h.P_u[:, None] + st[..., 1:] * h.P_v[:, None]
    j = draw_entries(cl.s[:, 0], cl.sw, cl.r[:, 0], k, rng)
    q = np.where(j >= 0, cl.s[np.maximum(j, 0), 1], -1)
    cent = h.P_o + np.where(tri, 1 / 3, 0.5)[:, None] * (h.P_u + h.P_v)
    return ClusterRays(bounds, np.searchsorted(cl.r[:, 0], np.arange(M + 1)), pts, cent, q)


def blocked_cluster_matrices(h: HR.Hierarchy, tris: np.ndarray, rng):
    """h's cluster matrices (:func:`clusters.cluster_matrices`) with the triangles in the room:
    the receiver weights of the links they block scaled as a session scales them
    (:class:`ClusterRays`); Relight's §4.5 path in a clustered room."""
    from .clusters import ClusterLinks, cluster_matrices

    cl = h.cluster_links()
    e, vf = cluster_rays(h, rng).factor(cl, tris)
    rw = cl.rw.copy()
    rw[e] *= vf
    return cluster_matrices(ClusterLinks(cl.V, cl.r, rw, cl.s, cl.sw), h.n_elems)


# ------------------------------------------------------------------------------------------
# placement


def check_placement(h: HR.Hierarchy, thing: Thing, port: str, names=None) -> None:
    """BadInput naming the object when it lies inside a wall (one of its edges crosses a real
    polygon, or a real polygon's edge crosses one of its triangles) or outside the room (a
    vertex outside the real polygons' bounding box)."""
    from nodes.common import rays

    what = "virtual light" if thing.light else "virtual object"
    pts = h.P_o[:, None] + np.stack([0 * h.P_u, h.P_u, h.P_u + h.P_v, h.P_v], 1)
    lo, hi = pts.reshape(-1, 3).min(0), pts.reshape(-1, 3).max(0)
    tol = 1e-6 * np.linalg.norm(hi - lo)
    v = thing.tris.reshape(-1, 3)
    if not np.all(np.isfinite(v)):
        raise BadInput(port, f"{what} '{thing.name}' has non-finite coordinates")
    # touching is not crossing: both sides' polygons shrink by EDGE of their size (a box on a
    # table may overhang its edge, one against a wall may touch it)
    e0 = thing.tris.reshape(-1, 3)
    e1 = thing.tris[:, [1, 2, 0]].reshape(-1, 3)
    occ = (h.P_o + EDGE * (h.P_u + h.P_v), (1 - 2 * EDGE) * h.P_u, (1 - 2 * EDGE) * h.P_v, h.P_n)
    hit = np.flatnonzero(rays.occluded(e0, e1, occ))
    pe0 = pts.reshape(-1, 3)
    pe1 = pts[:, [1, 2, 3, 0]].reshape(-1, 3)
    mid = thing.tris.mean(1, keepdims=True)
    back = np.flatnonzero(segments_hit(pe0, pe1, mid + (1 - 2 * EDGE) * (thing.tris - mid)))
    if len(hit) or len(back):
        p = _crossed_polygon(e0[hit], e1[hit], occ) if len(hit) else back[0] // 4
        wall = f"polygon '{names[p]}'" if names is not None and p < len(names) else f"the scene's polygon {p} (from 0, in the scene's order)"
        raise BadInput(port, f"{what} '{thing.name}' is inside a wall: it crosses {wall}")
    if np.any(v < lo - tol) or np.any(v > hi + tol):
        raise BadInput(port, f"{what} '{thing.name}' lies outside the room (its bounds "
                             f"{np.round(thing.lo, 3).tolist()}–{np.round(thing.hi, 3).tolist()}, "
                             f"the room's {np.round(lo, 3).tolist()}–{np.round(hi, 3).tolist()})")


def check_params_placement(h: HR.Hierarchy, vlights, vboxes) -> None:
    """Relight's virtual_lights / virtual_boxes params: each inside the room, none in a wall."""
    for L in vlights:
        check_placement(h, light_thing(L.name, L.center, L.size, L.normal, L.emittance),
                        "virtual_lights")
    for bx in vboxes:
        check_placement(h, box_thing(bx.name, bx.center, bx.size, bx.rotation_deg, bx.reflectance),
                        "virtual_boxes")


def _crossed_polygon(p0, p1, occ) -> int:
    """The first real polygon the segments cross (for the message)."""
    from nodes.common import rays

    for p in range(len(occ[0])):
        if rays.occluded(p0, p1, tuple(a[p:p + 1] for a in occ)).any():
            return p
    return 0


# ------------------------------------------------------------------------------------------
# the session


@dataclass(eq=False)
class _Placed:
    """A thing in the session with what it changed: real links re-evaluated (idx, V factor),
    its own gather rows (ΔK in COO: rows, cols, values over the extended elements)."""

    thing: Thing
    first: int  # index of its first patch among the extended leaves / elements
    links: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    vfac: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: a clustered room's receiver entries of cluster links it blocks, and their factors
    cl_e: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cl_vf: np.ndarray = field(default_factory=lambda: np.zeros(0))
    coo: tuple = ()
    reach: "_Reach | None" = None
    ahead: "_Scan | _Reach | None" = None  # the reach a drag will need next (see _look_ahead)
    pace: np.ndarray = field(default_factory=lambda: np.zeros(3))  # its steps, smoothed
    F: np.ndarray | None = None  # a light's form factors and visibility from each real leaf
    V: np.ndarray | None = None
    real: np.ndarray | None = None  # a light's rays (leaf, SOURCE_RAYS²) the real polygons block


@dataclass(eq=False)
class _Reach:
    """The real links whose shafts the box [lo, hi] (an object's bounds grown by REACH)
    crosses, with their shaft bounds, ray pack (M·LINK_RAYS² rays) and rays' kernel weights
    (M, LINK_RAYS²): while the object's bounds and their bounding sphere stay inside this
    box's, every link its shaft test finds is one of these, so a drag tests only these."""

    lo: np.ndarray
    hi: np.ndarray
    links: np.ndarray
    bounds: np.ndarray
    pack: tuple
    w: np.ndarray

    def holds(self, lo, hi) -> bool:
        return box_holds(self.lo, self.hi, lo, hi)


def box_holds(blo, bhi, lo, hi) -> bool:
    """Whether a reach's box [blo, bhi] holds bounds [lo, hi]: the box and its bounding sphere
    contain the bounds and theirs (then every link the shaft test finds for the bounds is one
    the box's finds)."""
    m, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    big = 0.5 * np.linalg.norm(bhi - blo) - 1e-3  # (1 mm: float32's rounding)
    return bool(np.all(lo >= blo) and np.all(hi <= bhi)
                and np.linalg.norm(m - 0.5 * (blo + bhi)) + r <= big)


@dataclass(eq=False)
class _Scan:
    """A reach being built ahead of a drag: the box [lo, hi] and the links whose shafts it
    crosses among the first ``done`` (a slice more per move)."""

    lo: np.ndarray
    hi: np.ndarray
    done: int = 0
    found: list = field(default_factory=list)


class VirtualSession:
    """Insert, move and remove virtual objects and lights on a preprocessed room (see the
    module docstring).  ``image()`` gives the relit photograph (H,W,3) float32."""

    def __init__(self, sol, un, proj, photo, camera, e_real=None, rho_fix=(0.5, 0.5, 0.5),
                 names=None, seed: int = 0):
        self.sol, self.camera, self.names = sol, camera, names
        self.e = sol.emit if e_real is None else np.asarray(e_real, float)
        h = self.h = sol.hierarchy()
        self.rng = np.random.default_rng(seed)
        self.ops = HR.operators(h)
        self.N0, self.L0 = h.n_elems, len(self.ops.leaves)
        lv = self.ops.leaves
        o, u, v, n, a = h.geom(lv)
        self.leaf_c, self.leaf_n, self.leaf_a = o + 0.5 * (u + v), n, a
        self.E0 = np.einsum("lsc,sc->lc", sol.resp - sol.rho[:, None, :] * sol.resp_H, self.e)
        self.B_ref, _ = HR.solve(self.ops, self.E0, sol.rho, tol=TOL * 0.1)
        self.bounds = link_bounds(h)
        every = np.arange(h.n_elems)
        self._ends = (element_points(h, every, LINK_RAYS), element_points(h, every, LINK_RAYS, True))
        self.occ = (h.P_o, h.P_u, h.P_v, h.P_n)
        self.cl, self.clusters = h.cluster_links(), cluster_rays(h, np.random.default_rng(seed + 1))
        self.roots = np.flatnonzero(h.parent == -1)
        self.root_of_poly = np.full(len(h.P_o), -1)
        self.root_of_poly[h.poly[self.roots]] = self.roots
        # the display: per pixel, the leaves' multipliers (Relight's plan at emittances e)
        self.plan = _pixel_plan_of(sol, proj, photo)
        self.f_leaf = np.einsum("lsc,sc->lc", leaf_multiplier(sol, un), self.e)
        glow = np.einsum("lsc,sc->lc", fixture_glow(sol, np.asarray(rho_fix, float)), self.e)
        self.glow_px = np.asarray(self.plan.glow @ glow)
        self.room_depth = self._room_depth(*self.plan.photo.shape[:2])
        self.things: dict[str, _Placed] = {}
        self._cover: dict = {}  # per thing, its screen box's coverage (see _coverage)
        self.B = self.B_ref
        self._K0c = self.ops.K.tocsc()
        self._Be0 = self.ops.pull @ self.B_ref
        self._y0 = self.ops.K @ self._Be0
        self.stats: dict = {}

    # -- public ------------------------------------------------------------------------------
    def insert(self, thing: Thing, port: str = "virtual_boxes") -> np.ndarray:
        if thing.name in self.things:
            raise BadInput(port, f"virtual object '{thing.name}' is already in the room")
        check_placement(self.h, thing, port, self.names)
        first = self.L0 + sum(len(p.thing.centre) for p in self.things.values())
        self.things[thing.name] = _Placed(thing, first)
        self._relink(thing.name, None)
        return self.update()

    def move(self, name: str, offset=None, rotation_deg: float = 0.0, to=None,
             port: str = "virtual_boxes") -> np.ndarray:
        """Move thing ``name`` by ``offset`` (or its bottom centre ``to``); BadInput (nothing
        changed) when the new place is outside the room or inside a wall."""
        p = self._placed(name, port)
        t = p.thing
        if to is not None:
            offset = np.asarray(to, float) - t.foot
        new = t.moved(np.zeros(3) if offset is None else offset, rotation_deg)
        check_placement(self.h, new, port, self.names)
        old_lo, old_hi = t.lo, t.hi
        p.thing = new
        self._relink(name, (old_lo, old_hi))
        return self.update()

    def remove(self, name: str) -> np.ndarray:
        p = self._placed(name, "virtual_boxes")
        bounds = (p.thing.lo, p.thing.hi)
        del self.things[name]
        self._cover.pop(name, None)
        first = self.L0
        for q in self.things.values():  # patches are numbered anew: their links too
            q.first, first = first, first + len(q.thing.centre)
        for q in self._objects():
            q.coo = self._object_links(q)
        for q in self._lights():
            redo = self._light_shafts(q.thing, [bounds])
            self._light_links(q, redo)
        self.B = self.B[:self.L0]
        return self.update()

    def handles(self) -> list[dict]:
        """Each thing's name, kind, bottom centre (world) and where it is in the image."""
        out = []
        for name, p in self.things.items():
            t = p.thing
            foot = t.foot
            xy = project(self.camera, np.concatenate([foot[None], t.tris.reshape(-1, 3)]))
            out.append({"name": name, "kind": "light" if t.light else "object",
                        "foot": foot.round(6).tolist(), "xy": xy[0].round(2).tolist(),
                        "box": [*xy[1:].min(0).round(2).tolist(), *xy[1:].max(0).round(2).tolist()]})
        return out

    # -- links -------------------------------------------------------------------------------
    def _placed(self, name, port):
        if name not in self.things:
            raise BadInput(port, f"no virtual object '{name}' (have: {', '.join(self.things) or 'none'})")
        return self.things[name]

    def _virtual_tris(self, but: str | None = None) -> np.ndarray:
        ts = [p.thing.tris for n, p in self.things.items() if n != but]
        return np.concatenate(ts) if ts else np.zeros((0, 3, 3))

    def _blocked(self, p0, p1, ignore_poly=None) -> np.ndarray:
        """Rays blocked by the real polygons (rays.occluded) or by any virtual triangle."""
        from nodes.common import rays

        ign = None if ignore_poly is None else np.stack([ignore_poly, np.full_like(ignore_poly, -1)], 1)
        return rays.occluded(p0, p1, self.occ, ignore=ign) | segments_hit(p0, p1, self._virtual_tris())

    def _relink(self, name: str, old_bounds) -> None:
        """Re-evaluate what thing ``name`` changes: for an object, the real links whose shafts
        its new bounds cross (those only its old bounds crossed drop back to their preprocessed
        V), its own links, and the virtual lights' links to the leaves whose shafts its old or
        new bounds cross; for a light, its links and the objects' links (they gather from it)."""
        p = self.things[name]
        t = p.thing
        if t.light:
            self.stats.pop("reach", None)
            self._light_links(p, None)
            for q in self._objects():
                q.coo = self._object_links(q)
            return
        lo, hi = t.lo - 1e-6, t.hi + 1e-6
        R, A, kind = p.reach, p.ahead, _ray_kind()
        step = None if old_bounds is None else 0.5 * (t.lo + t.hi - old_bounds[0] - old_bounds[1])
        fast = step is not None and np.abs(step).max() > REACH / 3
        self.stats["reach"] = "kept"
        if R is None or not R.holds(lo, hi) or R.pack[0] != kind:
            ready = isinstance(A, _Reach) and A.holds(lo, hi) and A.pack[0] == kind
            grow = 0.0 if fast else REACH  # (a fast drag would leave a reach at once)
            R = p.reach = A if ready else self._reach(lo - grow, hi + grow, R)
            p.ahead = None
            self.stats["reach"] = "ahead" if ready else "built"
        sel = shaft_crossed(R.bounds, lo, hi)
        idx, w = np.take(R.links, sel), np.take(R.w, sel, axis=0)
        vf = self._object_factor((R.pack[0], *(np.take(x, sel, axis=0).reshape(-1, 3)
                                               for x in R.pack[1:])), w, t.tris)
        keep = vf < 1.0  # a link the object does not block has no entry in ΔK
        p.links, p.vfac = idx[keep], vf[keep]
        if self.clusters is not None:
            p.cl_e, p.cl_vf = self.clusters.factor(self.cl, t.tris)
        p.coo = self._object_links(p)
        boxes = [(t.lo, t.hi)] + ([old_bounds] if old_bounds is not None else [])
        for q in self._lights():
            redo = self._light_shafts(q.thing, boxes)
            self._light_links(q, redo)
        self.stats["links_reevaluated"] = int(len(idx))
        if step is not None and not fast:
            self._look_ahead(p, step)

    def _objects(self):
        return [p for p in self.things.values() if not p.thing.light]

    def _lights(self):
        return [p for p in self.things.values() if p.thing.light]

    def _object_factor(self, pack: tuple, w: np.ndarray, tris: np.ndarray) -> np.ndarray:
        """V_object of real links from their rays (pack, weights w (M, LINK_RAYS²)): the
        rays' kernel-weighted unblocked share."""
        b = packed_hit(pack, tris).reshape(w.shape)
        out = np.ones(len(w))
        m = np.flatnonzero(b.any(1))  # the kernel only where a ray is blocked
        out[m] = weighted_visible(np.take(b, m, axis=0), np.take(w, m, axis=0))
        return out

    def _look_ahead(self, p: _Placed, step: np.ndarray) -> None:
        """Build the reach a drag at this ``step`` will need next, a slice of the links per
        move: the current reach's box moved REACH ahead in the drag's direction (its steps
        averaged, each weighing half the last average; by the largest component), the slices sized to be done by the time the object has room for one more
        step (a step over REACH / 3 finds its links on the spot, with no reach around them).
        It starts again when its box would not hold the object where, at this pace, it
        leaves the current reach.  What a
        move finds does not depend on it: only the time of the move that leaves a reach."""
        R, t = p.reach, p.thing
        way = p.pace = 0.5 * (p.pace + step)  # (a hand's jitter smoothed out)
        big = np.abs(way).max()
        if big <= 1e-9:
            return
        c, half = 0.5 * (R.lo + R.hi) + REACH * way / big, 0.5 * (R.hi - R.lo)
        room = np.where(step > 0, R.hi - t.hi, t.lo - R.lo) / np.maximum(np.abs(step), 1e-12)
        left = int(room.min())  # moves of this step the current reach still holds
        A, go = p.ahead, (left + 1) * way  # (where the object will be when it leaves R)
        if A is None or not box_holds(A.lo, A.hi, t.lo + go, t.hi + go):
            A = p.ahead = _Scan(c - half, c + half)
        if isinstance(A, _Reach):
            return
        M = len(self.h.recv)
        if A.done == M:  # the move after the last slice: its rays
            p.ahead = self._reach_of(A.lo, A.hi, R, A.found)
            return
        n = -(-(M - A.done) // max(1, left - 1))  # (the last move for the rays)
        b = min(M, A.done + -(-n // SCAN_ALIGN) * SCAN_ALIGN)
        part = self.bounds[:, A.done:b]
        A.found.append(self._part(A.done + shaft_crossed(part, A.lo, A.hi), R))
        A.done = b

    def _reach(self, lo, hi, old: _Reach | None) -> _Reach:
        """The links whose shafts [lo, hi] crosses, their bounds, rays and weights (those of
        the ``old`` reach's links kept: a drag leaves one reach for the next)."""
        return self._reach_of(lo, hi, old, [self._part(shaft_crossed(self.bounds, lo, hi), old)])

    def _part(self, links: np.ndarray, old: _Reach | None) -> tuple:
        """Links (sorted) of a reach being built: them, their places in the ``old`` reach
        (−1: not there, or its rays were cast another way) and their shaft bounds."""
        pos = np.full(len(links), -1)
        if old is not None and old.pack[0] == _ray_kind() and len(old.links):
            at = np.minimum(np.searchsorted(old.links, links), len(old.links) - 1)
            pos = np.where(old.links[at] == links, at, -1)
        sub = np.take(self.bounds, links, axis=1)
        return links, pos, sub

    def _reach_of(self, lo, hi, old: _Reach | None, parts: list) -> _Reach:
        """The reach [lo, hi] of the links in ``parts`` (see _part): the rays of those the old
        reach has taken from it, the others' cast anew."""
        links, pos = (np.concatenate([q[j] for q in parts]) for j in (0, 1))
        sub = np.concatenate([q[2] for q in parts], axis=1)
        k, new, h = LINK_RAYS * LINK_RAYS, np.flatnonzero(pos < 0), self.h
        r, s = h.recv[links[new]], h.send[links[new]]
        p0, p1 = np.take(self._ends[0], r, axis=0), np.take(self._ends[1], s, axis=0)
        kind, o, d = ray_pack(p0.reshape(-1, 3), p1.reshape(-1, 3))
        fresh = (o.reshape(-1, k, 3), d.reshape(-1, k, 3), ray_weights(h, r, s, p0, p1))
        out = []
        for j, f in enumerate(fresh):
            if len(new) < len(links):  # (then old's rays are of this kind: see _part)
                x = np.take((old.pack[1:] + (old.w,))[j], np.maximum(pos, 0), axis=0)
            else:
                x = np.empty((len(links), *f.shape[1:]), f.dtype)
            x[new] = f
            out.append(x)
        return _Reach(lo, hi, links, sub, (kind, out[0], out[1]), out[2])

    def _object_links(self, p: _Placed) -> tuple:
        """ΔK entries (rows, cols, F·V) of an object's patches: gathering from every real
        polygon (its root element) and every virtual light, giving to the real leaves near it."""
        t = p.thing
        pid = self._elem(p.first + np.arange(len(t.centre)))
        h = self.h
        senders = [(h.P_o, h.P_u, h.P_v, self.root_of_poly, np.arange(len(h.P_o)), h.tri_poly)]
        for q in self._lights():
            qo, qu, qv = _light_quad(q.thing)
            senders.append((qo, qu, qv, self._elem(np.array([q.first])), np.full(1, -1),
                            np.zeros(1, bool)))
        rows, cols, vals = [], [], []
        for so, su, sv, selem, spoly, tri in senders:
            F, V = self._point_to_polygons(t.centre, t.normal, so, su, sv, spoly, tri)
            r, s = np.nonzero(F * V > 0)
            rows.append(pid[r]); cols.append(selem[s]); vals.append((F * V)[r, s])
        near = self._near_leaves(t)
        Fk = _point_kernel(self.leaf_c[near], self.leaf_n[near], t.centre, t.normal, t.area)
        r, s = np.nonzero(Fk > 0)
        rows.append(self.ops.leaves[near[r]]); cols.append(pid[s]); vals.append(Fk[r, s])
        return tuple(np.concatenate(x) for x in (rows, cols, vals))

    def _light_links(self, p: _Placed, leaves: np.ndarray | None) -> None:
        """F and V of the real leaves ← virtual light p (point-to-polygon from the leaf centres):
        of every leaf when it is inserted, else of ``leaves`` (those whose shafts to it a moved
        object crossed).  A light does not move: its F and which of its rays the real polygons
        block are found once; the virtual triangles are cast again."""
        from nodes.common import rays

        qo, qu, qv = _light_quad(p.thing)
        if leaves is None:
            p.F = self._ff_front(self.leaf_c, self.leaf_n, qo, qu, qv)[:, 0]
            p.V, p.real = np.zeros(self.L0), np.zeros((self.L0, SOURCE_RAYS ** 2), bool)
        r = np.flatnonzero(p.F > 1e-9) if leaves is None else leaves[p.F[leaves] > 1e-9]
        if len(r) == 0:
            return
        p0, p1, ig = self._source_rays(self.leaf_c[r], self.leaf_n[r], qo, qu, qv, np.full(1, -1),
                                       np.arange(len(r)), np.zeros(len(r), int))
        if leaves is None:
            ign = np.stack([ig, np.full_like(ig, -1)], 1)
            p.real[r] = rays.occluded(p0, p1, self.occ, ignore=ign).reshape(len(r), -1)
        b = p.real[r] | segments_hit(p0, p1, self._virtual_tris()).reshape(len(r), -1)
        p.V[r] = 1.0 - b.mean(1)

    def _light_shafts(self, t: Thing, boxes) -> np.ndarray:
        """Real leaves whose shaft to light t may meet one of the boxes (lo, hi)."""
        c = t.centre[0]
        rl = 0.5 * np.linalg.norm(t.hi - t.lo) + np.sqrt(self.leaf_a)
        d = c - self.leaf_c
        out = np.zeros(self.L0, bool)
        for lo, hi in boxes:
            mid, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
            s = np.clip(np.einsum("nc,nc->n", mid - self.leaf_c, d) / np.maximum(np.einsum("nc,nc->n", d, d), 1e-300), 0, 1)
            out |= np.linalg.norm(self.leaf_c + s[:, None] * d - mid, axis=1) <= r + rl
        return np.flatnonzero(out)

    def _elem(self, leaf_idx):
        """Element index of extended leaves ≥ L0 (patches: one element each, after N0)."""
        return np.asarray(leaf_idx) - self.L0 + self.N0

    def _near_leaves(self, t: Thing) -> np.ndarray:
        """Real leaves within NEAR × t's radius that face it: a leaf whose plane has every
        vertex of t 1 µm or more behind it sees none of t's patches (their centres lie in
        t's hull), so its kernel row would be all zeros."""
        mid = 0.5 * (t.lo + t.hi)
        r = 0.5 * np.linalg.norm(t.hi - t.lo)
        near = np.flatnonzero(np.linalg.norm(self.leaf_c - mid, axis=1) < NEAR * r)
        c, n = self.leaf_c[near], self.leaf_n[near]
        ahead = n @ t.tris.reshape(-1, 3).T - np.einsum("mc,mc->m", n, c)[:, None]
        return near[ahead.max(1, initial=-np.inf) > -1e-6]

    def _point_to_polygons(self, x, n, so, su, sv, spoly, tri=None):
        """(M,K) form factors from points x (normals n) to polygons (o, u, v; triangles where
        ``tri``) and their visibility by SOURCE_RAYS² rays to stratified points on each.  In
        a clustered room (thousands of small polygons) a polygon whose diameter is below
        FAR × its distance from a point is a point there: its centroid, A cos cos / πr², one
        ray."""
        tri = np.zeros(len(so), bool) if tri is None else tri
        far = np.zeros((len(x), len(so)), bool)
        if self.clusters is not None:
            cen = so + np.where(tri, 1 / 3, 0.5)[:, None] * (su + sv)
            diam = 2 * np.linalg.norm(G.corners(so, su, sv, tri) - cen[:, None], axis=2).max(1)
            far = diam[None] < FAR * np.linalg.norm(x[:, None] - cen[None], axis=2)
            cr = np.cross(su, sv)
            jac = np.linalg.norm(cr, axis=1)
            Fp = _point_kernel(x + 1e-6 * n, n, cen, cr / jac[:, None], jac * np.where(tri, 0.5, 1))
        F = self._ff_front(x, n, so, su, sv, tri, ~far)
        V = np.zeros(F.shape)
        r, s = np.nonzero((F > 1e-9) & ~far)
        if len(r):
            p0, p1, ig = self._source_rays(x, n, so, su, sv, spoly, r, s, tri)
            V[r, s] = 1.0 - self._blocked(p0, p1, ig).reshape(len(r), -1).mean(1)
        if far.any():
            F[far] = Fp[far]
            r, s = np.nonzero(far & (F > 1e-9))
            V[r, s] = 1.0 - self._blocked(x[r] + 1e-6 * n[r], cen[s], spoly[s])
        return F, V

    @staticmethod
    def _ff_front(x, n, so, su, sv, tri=None, pairs=None) -> np.ndarray:
        """(M,K) point-to-polygon form factors, 0 where a point is behind one (those pairs,
        and those not in ``pairs`` (M,K), are not computed)."""
        front = np.einsum("mkc,kc->mk", x[:, None] - so[None], np.cross(su, sv)) > 0
        m, k = np.nonzero(front if pairs is None else front & pairs)
        F = np.zeros(front.shape)
        F[m, k] = G.ff_point_polygon(x[m] + 1e-6 * n[m], n[m], G.corners(so, su, sv, tri)[k])
        return F

    @staticmethod
    def _source_rays(x, n, so, su, sv, spoly, r, s, tri=None):
        """SOURCE_RAYS² rays (flat end points) from points x[r] to stratified points on the
        polygons s (triangles where ``tri``), and the polygon each ray is not blocked by (its
        own)."""
        st = G.grid_st(SOURCE_RAYS)[None]
        if tri is not None and tri.any():
            st = G.fold(np.broadcast_to(st, (len(s), *st.shape[1:])), tri[s][:, None])
        p1 = so[s][:, None] + st[..., 0:1] * su[s][:, None] + st[..., 1:2] * sv[s][:, None]
        p0 = np.broadcast_to((x[r] + 1e-6 * n[r])[:, None], p1.shape)
        return p0.reshape(-1, 3), p1.reshape(-1, 3), np.repeat(spoly[s], p1.shape[1])

    # -- radiosity and image -----------------------------------------------------------------
    def _system(self):
        """Extended E, ρ and ΔK of all things (links re-evaluated, own links)."""
        nv = sum(len(p.thing.centre) for p in self.things.values())
        N, L = self.N0 + nv, self.L0 + nv
        h = self.h
        objs = self._objects()
        idx, inv = _union([p.links for p in objs])
        vf = np.ones(len(idx))
        np.multiply.at(vf, inv, np.concatenate([p.vfac for p in objs] + [np.zeros(0)]))
        sub = HR.Hierarchy(**{k: getattr(h, k) for k in HR.Hierarchy.ARRAYS})
        sub.recv, sub.send = np.take(h.recv, idx), np.take(h.send, idx)
        rows, cols, vals = ([x] for x in HR.link_entries(
            sub, np.take(h.F, idx) * np.take(h.V, idx) * (vf - 1.0), np.take(h.C, idx, axis=0)[:, :2]))
        for p in self._objects():
            rows.append(p.coo[0]); cols.append(p.coo[1]); vals.append(p.coo[2])
        for p in self._lights():
            ok = np.flatnonzero(p.F * p.V > 0)
            rows.append(self.ops.leaves[ok]); cols.append(np.full(len(ok), self._elem(p.first)))
            vals.append((p.F * p.V)[ok])
        K = _Entries(np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64),
                     np.concatenate(vals), N)
        E = np.zeros((L, 3))
        rho = np.zeros((L, 3))
        E[:self.L0], rho[:self.L0] = self.E0, self.sol.rho
        for p in self.things.values():
            sl = slice(p.first, p.first + len(p.thing.centre))
            E[sl], rho[sl] = p.thing.emit, p.thing.rho
        return E, rho, K, nv

    def _cluster_delta(self) -> _Entries:
        """ΔW of a clustered room's cluster links (:class:`ClusterRays`): the receiver weights
        a_p/π times (the objects' factors − 1) where they block; irradiance ΔW @ (U @ Be)."""
        objs = self._objects()
        e, inv = _union([p.cl_e for p in objs])
        vf = np.ones(len(e))
        np.multiply.at(vf, inv, np.concatenate([p.cl_vf for p in objs] + [np.zeros(0)]))
        return _Entries(self.cl.r[e, 1], self.cl.r[e, 0], self.cl.rw[e] / np.pi * (vf - 1.0),
                        self.N0)

    def update(self) -> np.ndarray:
        """Iterate B = E + ρ·gather(B) with K₀ + ΔK from the last B; the relit image."""
        E, rho, dK, nv = self._system()
        ops = self.ops
        dC = None if ops.Kc is None else self._cluster_delta()
        B = E.copy()  # warm start: the last B (patches added since start at E)
        n = min(len(B), len(self.B))
        B[:n] = self.B[:n]
        scale = max(np.abs(E).max(), 1e-300)
        it = 0
        for it in range(1, MAX_ITER + 1):
            Be = np.concatenate([ops.pull @ B[:self.L0], B[self.L0:]])
            H = dK @ Be
            H[:self.N0] += self._gather0(Be[:self.N0], TOL * scale)
            if dC is not None:  # a clustered room's cluster links, less what objects block
                y = ops.Kc[1] @ Be[:self.N0]
                H[:self.N0] += ops.Kc[0] @ y + dC @ y
            Hl = np.concatenate([ops.push @ H[:self.N0], H[self.N0:]])
            Bn = E + rho * Hl
            d = np.abs(Bn - B).max()
            B = Bn
            if d <= TOL * scale:
                break
        self.B = B
        self.stats.update(iterations=it, patches=nv)
        return self.image()

    def _gather0(self, Be: np.ndarray, thr: float) -> np.ndarray:
        """K₀ @ Be, kept up to date column by column: only the elements whose radiosity moved
        by more than ``thr`` since they were last gathered are (K₀ in CSC: their columns)."""
        diff = Be - self._Be0
        cols = np.flatnonzero(np.abs(diff).max(1) > thr)
        if len(cols):
            self._y0 += self._K0c[:, cols] @ diff[cols]
            self._Be0[cols] = Be[cols]
        return self._y0.copy()

    def image(self) -> np.ndarray:
        B = self.B
        ratio = np.where(self.B_ref > 1e-12, B[:self.L0] / np.maximum(self.B_ref, 1e-12), 1.0)
        f = self.f_leaf[self.plan.near] * ratio
        R = np.asarray(self.plan.surface @ f)
        out = self.plan.photo.copy()
        flat = out.reshape(-1, 3)
        flat[self.plan.index] = self.plan.base * R + self.glow_px
        if self.things:
            self._draw(out)
        return out

    def _draw(self, out: np.ndarray) -> None:
        """Virtual things over the image: SUB² rays per pixel of each thing's screen box, each
        the nearest of the room (its depth, once per session) and the things; a thing's sample
        shows its patch's B/π."""
        H, W = out.shape[:2]
        hds = self.handles()
        things = [p.thing for p in self.things.values()]
        first = np.cumsum([0] + [len(t.tris) for t in things])
        cam = self.camera
        front = [np.all((t.tris.reshape(-1, 3) - cam.position) @ cam.pose[2, :3] > 0)
                 for t in things]
        for hd in hds:
            x0, y0 = (max(0, int(np.floor(c)) - 1) for c in hd["box"][:2])
            x1, y1 = int(min(W, np.ceil(hd["box"][2]) + 1)), int(min(H, np.ceil(hd["box"][3]) + 1))
            if x1 <= x0 or y1 <= y0:
                continue
            # the things that may show here: screen boxes overlapping (wholly in front), in order
            parts = tuple((int(first[j]), things[j]) for j, q in enumerate(hds)
                          if not front[j] or (q["box"][0] <= x1 and q["box"][2] >= x0
                                              and q["box"][1] <= y1 and q["box"][3] >= y0))
            tri, hit, x = self._coverage(hd["name"], (x0, y0, x1, y1), parts)
            L = np.zeros((len(hit), 3))
            if hit.any():
                L[hit] = self._patch_radiance(tri[hit], x)
            k = SUB * SUB
            cov = hit.reshape(-1, k).mean(1)
            Lm = L.reshape(-1, k, 3).sum(1) / k
            blk = out[y0:y1, x0:x1].reshape(-1, 3)
            out[y0:y1, x0:x1] = (blk * (1 - cov)[:, None] + Lm).reshape(y1 - y0, x1 - x0, 3)

    def _coverage(self, name: str, box: tuple, parts: tuple):
        """Per subsample ray of the screen box (x0, y0, x1, y1) of thing ``name``: the virtual
        triangle it meets first (-1: none; triangles numbered over all things), whether that is
        in front of the room, and the hit points.  ``parts``: (first triangle, thing) of the
        things that may show there; kept while the box and these things stay the same (a drag
        moves one thing: the others' boxes are not cast again)."""
        from .textures import rays_at

        key = (box, parts)  # (things compare by identity: a moved thing is a new one)
        if self._cover.get(name, (None,))[0] == key:
            return self._cover[name][1]
        x0, y0, x1, y1 = box
        g = (np.arange(SUB) + 0.5) / SUB
        ys, xs = np.mgrid[y0:y1, x0:x1]
        X = (xs.ravel()[:, None] + np.tile(g, SUB)[None]).ravel()
        Y = (ys.ravel()[:, None] + np.repeat(g, SUB)[None]).ravel()
        o, d = rays_at(self.camera, X, Y)
        sel = np.concatenate([f + np.arange(len(t.tris)) for f, t in parts])
        tri, t_v = _first_triangle(o, d, np.concatenate([t.tris for _, t in parts]))
        tri = np.where(tri >= 0, sel[np.maximum(tri, 0)], -1)
        hit = (tri >= 0) & (t_v < self.room_depth[y0:y1, x0:x1].reshape(-1))
        self._cover[name] = (key, (tri, hit, o[hit] + t_v[hit, None] * d[hit]))
        return self._cover[name][1]

    def _room_depth(self, H: int, W: int) -> np.ndarray:
        """(H, W, SUB²) distance to the room along each subsample ray (pixel-major as _draw),
        through the ray backend (textures.first_hit; triangles as triangles)."""
        from .textures import first_hit, rays_at

        g = (np.arange(SUB) + 0.5) / SUB
        ys, xs = np.mgrid[0:H, 0:W]
        X = (xs.ravel()[:, None] + np.tile(g, SUB)[None]).ravel()
        Y = (ys.ravel()[:, None] + np.repeat(g, SUB)[None]).ravel()
        o, d = rays_at(self.camera, X, Y)
        _, t, _, _ = first_hit(o, d, (*self.occ, self.h.tri_poly))
        return t.reshape(H, W, SUB * SUB)

    def _patch_radiance(self, tri: np.ndarray, x: np.ndarray) -> np.ndarray:
        """B/π of the patch under world points x on virtual triangles ``tri`` (a box face's
        n×n patch by (s, t) in the face; a mesh's triangle; a light's front only)."""
        out = np.zeros((len(tri), 3))
        t0 = 0
        for p in self.things.values():
            t = p.thing
            m = (tri >= t0) & (tri < t0 + len(t.tris))
            t0 += len(t.tris)
            if not m.any():
                continue
            local = tri[m] - (t0 - len(t.tris))
            if t.quads is not None:
                nq = len(t.quads)
                face = local % nq
                n = t.faces[0]
                o, u, v, nrm, _ = G.frame(t.quads)
                du, dv = _dual(u, v)
                q = x[m] - o[face]
                s = np.clip((np.einsum("nc,nc->n", q, du[face]) * n).astype(int), 0, n - 1)
                tt = np.clip((np.einsum("nc,nc->n", q, dv[face]) * n).astype(int), 0, n - 1)
                patch = face * n * n + s * n + tt
                val = self.B[p.first + patch] / np.pi
                if t.light:  # the back of a light is black
                    back = np.einsum("nc,nc->n", self.camera.position - x[m], nrm[face]) < 0
                    val[back] = 0.0
            else:
                val = self.B[p.first + local] / np.pi
            out[m] = val
        return out


@dataclass(eq=False)
class _Entries:
    """ΔK as its entries (duplicates kept): built anew on every move, so never sorted into CSR;
    ``@`` sums each channel with one bincount."""

    rows: np.ndarray
    cols: np.ndarray
    vals: np.ndarray
    n: int

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        return np.stack([np.bincount(self.rows, self.vals * x[self.cols, c], minlength=self.n)
                         for c in range(x.shape[1])], 1).astype(float)  # (no entries: ints)


def _union(runs: list) -> tuple:
    """np.unique(np.concatenate(runs), return_inverse=True) of sorted runs (each object's
    links): a stable sort merges the runs in about linear time, where np.unique's quicksort
    does not see them."""
    x = np.concatenate(runs + [np.zeros(0, np.int64)])
    perm = np.argsort(x, kind="stable")
    s = np.take(x, perm)
    first = np.ones(len(s), bool)
    np.not_equal(s[1:], s[:-1], out=first[1:])
    inv = np.empty(len(x), np.intp)
    inv[perm] = np.cumsum(first) - 1
    return s[first], inv


def _dual(u, v):
    from nodes.common.rays import dual_basis

    return dual_basis(u, v)


def _light_quad(t: Thing):
    o, u, v, _, _ = G.frame(t.quads)
    return o, u, v


def _point_kernel(x, n, y, m, area):
    """(M,K) F from points x (normals n) to small patches y (normals m, areas): A cos cos / πr²,
    bounded by the disc of the patch's area seen head-on."""
    d = y[None] - x[:, None]
    r2 = np.maximum(np.einsum("mkc,mkc->mk", d, d), 1e-12)
    ci = np.clip(np.einsum("mkc,mc->mk", d, n), 0, None)
    cj = np.clip(-np.einsum("mkc,kc->mk", d, m), 0, None)
    F = area[None] * ci * cj / (np.pi * r2 * r2)
    return np.minimum(F, area[None] / (area[None] + np.pi * r2))


def _first_triangle(o, d, tris):
    """Nearest triangle hit along rays (two-sided): index (-1 none), t."""
    t = _triangle_t(o, d, tris)
    with np.errstate(invalid="ignore"):
        t = np.where(t > 1e-9, t, np.inf)  # (NaN compares False: a miss)
    k = np.argmin(t, 1)
    tk = t[np.arange(len(o)), k]
    return np.where(np.isfinite(tk), k, -1), tk


def project(cam, x: np.ndarray) -> np.ndarray:
    """Image coordinates (px) of world points x (N,3)."""
    xc = (x - cam.position) @ cam.pose[:3, :3].T
    return np.stack([cam.fx * xc[:, 0] / xc[:, 2] + cam.cx, cam.fy * xc[:, 1] / xc[:, 2] + cam.cy], 1)


def _pixel_plan_of(sol, proj, photo):
    """Relight's pixel plan (display.pixel_plan) with the leaves' nearest seen leaf."""
    from .display import nearest_seen, pixel_plan
    from .relight import emitter_polygons, photo_emitter_radiance

    h = sol.hierarchy()
    emit_poly = emitter_polygons(h, sol.leaves, emitter_leaves(sol))
    plan = pixel_plan(h, proj, photo, emit_poly, photo_emitter_radiance(sol, proj, emit_poly),
                      leaf_radiance=sol.T @ LUM)
    plan.near = nearest_seen(h, np.all(np.isfinite(sol.T), 1))
    return plan
