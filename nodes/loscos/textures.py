"""ProjectTextures: the photograph de-warped onto each polygon from the fixed viewpoint (§3)."""
from __future__ import annotations

import math

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Node
from nodes.common import rays

from . import checks
from . import geometry as G
from .ports import PROJECTION, ROOM_SCENE, Projection, RoomScene


SUB = 4  # subsamples per pixel side where a pixel may see more than one polygon


def rays_at(cam: Camera, x: np.ndarray, y: np.ndarray):
    """World-space ray origins and unit directions through image points (x, y) in pixels."""
    dc = np.stack([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, np.ones_like(x)], -1)
    d = dc.reshape(-1, 3) @ cam.pose[:3, :3]  # camera → world (R orthonormal)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(cam.position, d.shape).copy(), d


def camera_rays(cam: Camera, step: int = 1):
    """World-space ray origins and unit directions through pixel centres, (H//step·W//step, 3)."""
    ys = np.arange(0, cam.height, step) + 0.5
    xs = np.arange(0, cam.width, step) + 0.5
    X, Y = np.meshgrid(xs, ys)
    o, d = rays_at(cam, X, Y)
    return o, d, (len(ys), len(xs))


#: Embree's float32 hits this close (in s or t) to a polygon's edge are cast again in float64
EDGE_EPS = 1e-4


def first_hit(o: np.ndarray, d: np.ndarray, occ) -> tuple:
    """geometry.ray_first_hit (two-sided) through the ray backend (:mod:`nodes.common.rays`).

    With Embree, the polygon it hits first gives (t, s, tt) in float64; a ray whose hit lies
    within EDGE_EPS of the polygon's edge (where float32 may pick the neighbour) is cast again
    by the reference, so the two backends answer alike but for near-ties in depth."""
    if rays.backend() != "embree" or not len(o) or not len(occ[0]):
        return G.ray_first_hit(o, d, *occ[:4], two_sided=True, tri=occ[4])
    po, pu, pv, pn, tri = occ
    sc, prim_poly = rays.scene(occ)
    prim = sc.run(o.astype(np.float32), d.astype(np.float32), output=1)["primID"]
    idx = np.where(prim >= 0, prim_poly[np.maximum(prim, 0)], -1)
    t, s, tt = np.full(len(o), np.inf), np.zeros(len(o)), np.zeros(len(o))
    m = np.flatnonzero(idx >= 0)
    k = idx[m]
    den = np.einsum("nc,nc->n", d[m], pn[k])
    ok = np.abs(den) > 1e-14
    t[m] = np.einsum("nc,nc->n", po[k] - o[m], pn[k]) / np.where(ok, den, 1.0)
    q = o[m] + t[m, None] * d[m] - po[k]
    du, dv = G.dual_basis(pu, pv)
    s[m], tt[m] = np.einsum("nc,nc->n", q, du[k]), np.einsum("nc,nc->n", q, dv[k])
    rim = np.minimum.reduce([s[m], tt[m], 1 - s[m], 1 - tt[m],
                             np.where(tri[k], 1 - s[m] - tt[m], 1.0)])
    redo = np.concatenate([m[~ok | (rim < EDGE_EPS) | (t[m] <= 1e-9)], np.flatnonzero(idx < 0)])
    idx[redo], t[redo], s[redo], tt[redo] = G.ray_first_hit(o[redo], d[redo], *occ[:4],
                                                            two_sided=True, tri=tri)
    return idx, t, np.clip(s, 0, 1), np.clip(tt, 0, 1)


def first_polygon(verts: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Polygon index (-1: none or a back face) and (s, t) first hit along each ray."""
    po, pu, pv, pn, _ = G.frame(verts)
    idx, t, s, tt = first_hit(o, d, (po, pu, pv, pn, G.is_triangle(verts)))
    m = idx >= 0
    back = np.zeros(len(idx), bool)
    back[m] = np.einsum("nc,nc->n", d[m], pn[idx[m]]) > 0
    return np.where(back, -1, idx), np.stack([s, tt], -1)


def pixel_map(verts: np.ndarray, cam: Camera, step: int = 1):
    """Polygon index (-1: none or a back face) and (s, t) seen at each pixel centre."""
    o, d, shape = camera_rays(cam, step)
    idx, st = first_polygon(verts, o, d)
    return idx.reshape(shape), st.reshape(shape + (2,))


def edge_subsamples(verts: np.ndarray, cam: Camera, pix_poly: np.ndarray, k: int = SUB):
    """The pixels that see more than one polygon (or a polygon and nothing), found by
    casting k×k rays through the pixels next to a change of the centre map.

    Returns flat pixel indices (n,), the polygon (n, k²) and (s, t) (n, k², 2) seen by each
    subsample (subsample centres at ((i + ½)/k, (j + ½)/k) inside the pixel).
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    cand = np.flatnonzero(maximum_filter(pix_poly, 3, mode="nearest")
                          != minimum_filter(pix_poly, 3, mode="nearest"))
    if not len(cand):
        return np.zeros(0, np.int64), np.zeros((0, k * k), np.int64), np.zeros((0, k * k, 2))
    y, x = np.divmod(cand, pix_poly.shape[1])
    g = (np.arange(k) + 0.5) / k
    gy, gx = np.meshgrid(g, g, indexing="ij")
    X = x[:, None] + gx.ravel()[None]
    Y = y[:, None] + gy.ravel()[None]
    o, d = rays_at(cam, X, Y)
    idx, st = first_polygon(verts, o, d)
    idx = idx.reshape(len(cand), k * k)
    st = st.reshape(len(cand), k * k, 2)
    mixed = (idx != idx[:, :1]).any(1)
    return cand[mixed], idx[mixed], st[mixed]


def clip_convex(poly: list, axis: int, value: float, keep_below: bool) -> list:
    """Sutherland–Hodgman: the part of a convex 2-D polygon on one side of x[axis] = value."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina = (a[axis] <= value) if keep_below else (a[axis] >= value)
        inb = (b[axis] <= value) if keep_below else (b[axis] >= value)
        if ina:
            out.append(a)
        if ina != inb:
            t = (value - a[axis]) / (b[axis] - a[axis])
            out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
    return out


def area_centroid(poly: list):
    """Area and centroid of a simple 2-D polygon (shoelace)."""
    if len(poly) < 3:
        return 0.0, (0.0, 0.0)
    P = np.asarray(poly)
    x, y = P[:, 0], P[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cr = x * yn - xn * y
    A = cr.sum() / 2
    if abs(A) < 1e-12:
        return 0.0, (float(x.mean()), float(y.mean()))
    return abs(A), (float(((x + xn) * cr).sum() / (6 * A)), float(((y + yn) * cr).sum() / (6 * A)))


def image_outline(quad: np.ndarray, cam: Camera, near: float = 1e-4):
    """A polygon's outline in pixel coordinates (convex; clipped to z > near) or None."""
    pc = quad @ cam.pose[:3, :3].T + cam.pose[:3, 3]
    pts = [tuple(p) for p in pc]
    out = []
    for i in range(len(pts)):  # clip against the near plane in camera space
        a, b = np.array(pts[i]), np.array(pts[(i + 1) % len(pts)])
        if a[2] > near:
            out.append(a)
        if (a[2] > near) != (b[2] > near):
            out.append(a + (near - a[2]) / (b[2] - a[2]) * (b - a))
    if len(out) < 3:
        return None
    c = np.array(out)
    return np.stack([cam.fx * c[:, 0] / c[:, 2] + cam.cx, cam.fy * c[:, 1] / c[:, 2] + cam.cy], 1)


def inside_convex(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether points lie inside a convex 2-D polygon (either winding)."""
    e = np.roll(poly, -1, 0) - poly
    c = (e[:, 0][None] * (y[..., None] - poly[:, 1][None])
         - e[:, 1][None] * (x[..., None] - poly[:, 0][None]))
    return (c >= 0).all(-1) | (c <= 0).all(-1)


def emitter_coverage(verts, emitters, cam: Camera, pix_poly, sub_pix, sub_poly, k: int = SUB):
    """Exact share of each pixel covered by each emitter polygon (front side), and where on it.

    The emitter's outline is clipped with every pixel square it touches (its area is the
    coverage, the clipped part's centroid, traced back onto the emitter, the (s, t) it shows);
    the share hidden by nearer polygons comes from the pixel's subsamples (or its centre).
    Returns rows (pixel (m,), emitter polygon (m,), coverage (m,) in [0, 1], st (m,2)).
    """
    H, W = pix_poly.shape
    sub_row = np.full(H * W, -1)
    sub_row[sub_pix] = np.arange(len(sub_pix))
    g = (np.arange(k) + 0.5) / k
    gy, gx = np.meshgrid(g, g, indexing="ij")
    rows = []
    po, pu, pv, pn, _ = G.frame(verts)
    du, dv = G.dual_basis(pu, pv)
    for p in emitters:
        if np.dot(cam.position - po[p], pn[p]) <= 0:
            continue  # seen from behind: one-sided emitters show nothing
        out = image_outline(verts[p], cam)
        if out is None:
            continue
        x0, y0 = np.floor(out.min(0)).astype(int)
        x1, y1 = np.ceil(out.max(0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if x0 >= x1 or y0 >= y1:
            continue
        X, Y = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
        X, Y = X.ravel(), Y.ravel()
        corner_in = np.stack([inside_convex(out, X + a, Y + b)
                              for a in (0, 1) for b in (0, 1)], 1)
        full = corner_in.all(1)
        cov = np.where(full, 1.0, 0.0)
        cx, cy = X + 0.5, Y + 0.5
        poly2 = [tuple(q) for q in out]
        for i in np.flatnonzero(~full):
            q = poly2
            for axis, val, below in ((0, X[i], False), (0, X[i] + 1, True),
                                     (1, Y[i], False), (1, Y[i] + 1, True)):
                q = clip_convex(q, axis, val, below)
                if len(q) < 3:
                    break
            a, (mx, my) = area_centroid(q)
            cov[i], cx[i], cy[i] = min(a, 1.0), mx, my
        m = cov > 1e-9
        X, Y, cov, cx, cy = X[m], Y[m], cov[m], cx[m], cy[m]
        pix = Y * W + X
        # the share that nearer polygons hide
        vis = np.ones(len(pix))
        r = sub_row[pix]
        for i in np.flatnonzero(r >= 0):
            sx, sy = X[i] + gx.ravel(), Y[i] + gy.ravel()
            inq = inside_convex(out, sx, sy)
            if inq.any():
                vis[i] = np.mean(sub_poly[r[i]][inq] == p)
        cen = r < 0
        vis[cen] = np.where(inside_convex(out, X[cen] + 0.5, Y[cen] + 0.5),
                            (pix_poly.reshape(-1)[pix[cen]] == p).astype(float), 1.0)
        cov = cov * vis
        m = cov > 1e-9
        o, d = rays_at(cam, cx[m], cy[m])
        t = ((po[p] - o) @ pn[p]) / np.where(np.abs(d @ pn[p]) > 1e-12, d @ pn[p], 1e-12)
        q = o + t[:, None] * d - po[p]
        st = np.clip(np.stack([q @ du[p], q @ dv[p]], 1), 0.0, 1.0)
        rows.append((pix[m], np.full(m.sum(), p), cov[m], st))
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2))
    return tuple(np.concatenate(x) for x in zip(*rows))


def pure_pixels(pix_poly: np.ndarray, sub_pix: np.ndarray, em_pix=None, em_cover=None):
    """(H,W) polygon seen by the whole pixel (-1: none, or more than one polygon)."""
    out = pix_poly.copy()
    out.reshape(-1)[sub_pix] = -1
    if em_pix is not None:
        out.reshape(-1)[em_pix[em_cover < 1 - 1e-6]] = -1
    return out


def sample_bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of img (H,W,C) at continuous pixel coords (pixel centres at +0.5)."""
    from scipy.ndimage import map_coordinates

    out = np.empty(x.shape + (img.shape[2],), np.float64)
    for c in range(img.shape[2]):
        out[..., c] = map_coordinates(img[:, :, c], [y - 0.5, x - 0.5], order=1, mode="nearest")
    return out


def project(scene: RoomScene, cam: Camera, photo: np.ndarray, res: int) -> Projection:
    """Per-polygon res×res textures and the per-pixel polygon map (see Projection)."""
    verts = scene.verts
    po, pu, pv, pn, _ = G.frame(verts)
    P = len(verts)
    st = (np.arange(res) + 0.5) / res
    S, T = np.meshgrid(st, st, indexing="ij")
    pts = (po[:, None, None] + S[None, ..., None] * pu[:, None, None]
           + T[None, ..., None] * pv[:, None, None]).reshape(-1, 3)
    uv, z = cam.project(pts)
    c = cam.position
    front = (np.einsum("pc,pc->p", c[None] - po, pn) > 0)
    inside = (z > 1e-6) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) \
        & (uv[:, 1] < cam.height)
    inside &= np.repeat(front, res * res)
    tri = G.is_triangle(verts)
    if tri.any():  # a triangle's texels past its diagonal are not on it
        inside &= ~np.repeat(tri, res * res) | np.tile((S + T).ravel() <= 1, P)
    # occlusion: segment texel → camera blocked by another polygon
    cand = np.flatnonzero(inside)
    pid = np.repeat(np.arange(P), res * res)
    ign = np.stack([pid[cand], np.full(len(cand), -1)], 1)
    blocked = rays.occluded(pts[cand], np.broadcast_to(c, (len(cand), 3)),
                            (po, pu, pv, pn, tri), ignore=ign)
    cov = np.zeros(len(pts), bool)
    cov[cand[~blocked]] = True
    pp, pst = pixel_map(verts, cam)
    sub_pix, sub_poly, sub_st = edge_subsamples(verts, cam, pp)
    emitters = [p for p in range(P) if scene.light[p]]
    em = emitter_coverage(verts, emitters, cam, pp, sub_pix, sub_poly)
    # a texel is seen only where every pixel its bilinear sample reads sees the texel's
    # polygon alone: pixels that mix an emitter with the wall next to it (or any two
    # surfaces) would bias reflectances and emittances
    pure = pure_pixels(pp, sub_pix, em[0], em[2])
    c = np.flatnonzero(cov)
    x0 = np.floor(uv[c, 0] - 0.5).astype(np.int64)
    y0 = np.floor(uv[c, 1] - 0.5).astype(np.int64)
    ok = np.ones(len(c), bool)
    for dx in (0, 1):
        for dy in (0, 1):
            xx = np.clip(x0 + dx, 0, cam.width - 1)
            yy = np.clip(y0 + dy, 0, cam.height - 1)
            ok &= pure[yy, xx] == pid[c]
    cov[c[~ok]] = False
    tex = np.zeros((len(pts), 3))
    tex[cov] = sample_bilinear(photo, uv[cov, 0], uv[cov, 1])
    radiance, seen = emitter_photo_radiance(photo, pp, sub_pix, em, emitters, P)
    return Projection(tex.reshape(P, res, res, 3).astype(np.float32),
                      cov.reshape(P, res, res).astype(np.float32), pp, pst,
                      sub_pix, sub_poly, sub_st.astype(np.float64), *em, radiance, seen)


def emitter_photo_radiance(photo, pix_poly, sub_pix, em, emitters, P):
    """Each emitter's radiance in the photograph, from every pixel it covers.

    A pixel that an emitter covers by c shows P = c·L + (1 − c)·S, S the radiance of the
    nearest pixels that see one non-emitter polygon alone (display.surround_radiance), so
    L = Σ c (P − (1 − c) S) / Σ c² over the pixels that emitter alone covers.  An emitter seen
    at a grazing angle may fill no pixel: its rim pixels still measure it.  Returns (P,3)
    radiance (NaN where not seen) and (P,) the covered area in pixels.
    """
    from .display import surround_radiance

    em_pix, em_poly, em_cover, _ = em
    H, W = pix_poly.shape
    radiance = np.full((P, 3), np.nan)
    seen = np.bincount(em_poly, em_cover, minlength=P)[:P].astype(float)
    if not len(em_pix):
        return radiance, seen
    is_em = np.zeros(P + 1, bool)
    is_em[list(emitters)] = True
    pure = pure_pixels(pix_poly, sub_pix, em_pix, em_cover).reshape(-1)
    S = surround_radiance(photo, ((pure >= 0) & ~is_em[pure]).reshape(H, W)).reshape(-1, 3)
    n_em = np.bincount(em_pix, minlength=H * W)
    c_tot = np.bincount(em_pix, em_cover, minlength=H * W)
    alone = n_em[em_pix] == 1
    flat = photo.reshape(-1, 3)
    rest = np.where((c_tot[em_pix] < 1 - 1e-6)[:, None], S[em_pix], 0.0)
    ok = alone & np.isfinite(rest).all(1)
    c = em_cover[ok]
    y = flat[em_pix[ok]] - (1 - c)[:, None] * np.nan_to_num(rest[ok])
    num = np.zeros((P, 3))
    np.add.at(num, em_poly[ok], c[:, None] * y)
    den = np.bincount(em_poly[ok], c * c, minlength=P)[:P]
    has = den > 1e-9
    radiance[has] = num[has] / den[has, None]
    return radiance, seen


def texture_side(n_poly: int, resolution: int, budget: int) -> int:
    """Texels per polygon side: ``resolution``, fewer where n_poly·side² would pass ``budget``
    (4 at least).  One side for every polygon: Projection is a (P, R, R) array."""
    return int(min(resolution, max(4, math.isqrt(budget // max(n_poly, 1)))))


class ProjectTextures(Node):
    """Project the photograph onto every polygon: one res×res texture per polygon (§3, §4),
    res the ``resolution`` param, or less where the scene's polygons would pass the
    ``texel_budget`` at that size (a large triangle mesh; :func:`texture_side`).

    A texel (s, t) of polygon p is the point o + s·u + t·v (metres); it is seen when it lies in
    the camera frame in front of the polygon, no other polygon blocks the segment to the
    camera, and the (up to four) pixels its bilinear sample reads see polygon p alone; its
    value is the photograph bilinearly sampled there (linear radiance).  Also records, for
    each pixel, the polygon it sees and its (s, t), and for the pixels that see more than one
    polygon (edges, the rim of a light) what each of 4×4 subsamples sees; Relight uses these
    to treat mixed pixels by their coverage.
    """

    version = "3"
    inputs = {"scene": ROOM_SCENE, "camera": Camera,
              "photo": In(Image, "the photograph (linear RGB; an alpha channel is ignored)",
                          channels=(3, 4), same_size_as="camera")}
    outputs = {"projection": PROJECTION}

    @classmethod
    def examples(cls):
        """The ray-casting backends' conformance case: a small room with a box (embree.py)."""
        from .embree import RAY_PARAMS, ray_examples

        e = ray_examples()
        return [(RAY_PARAMS["ProjectTextures"],
                 {"scene": e["scene"], "camera": e["camera"], "photo": e["photo"]})]

    class Params(Node.Params):
        resolution: int = Field(128, ge=4, le=1024,
                                description="texels per polygon side, at most (see texel_budget)")
        texel_budget: int = Field(
            1 << 22, ge=1, le=1 << 28,
            description="texels of the whole scene: a scene of P polygons gets "
                        "min(resolution, ⌊√(texel_budget / P)⌋) texels per side, 4 at least "
                        "(a triangle mesh of 20k polygons: 14² each)")

    def compute(self, scene: RoomScene, camera: Camera, photo: Image):
        checks.pinhole(camera, "camera", "the Loscos pipeline needs")
        res = texture_side(len(scene.verts), self.params.resolution, self.params.texel_budget)
        pr = project(scene, camera, photo.pixels[:, :, :3].astype(np.float64), res)
        if not (pr.pix_poly >= 0).any():
            raise BadInput("camera", "the camera sees no polygon of the scene")
        return pr
