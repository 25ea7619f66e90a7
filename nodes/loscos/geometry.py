"""Geometry kernels of the Loscos 2000 radiosity system, each in one place, vectorised.

* :func:`ff_point_polygon` — the differential-area → polygon form factor by Lambert's contour
  integral (exact for an unoccluded polygon, after clipping it to the receiver's hemisphere).
* :func:`element_form_factors` — element → element form factors F_ij (Loscos 2000 §2.3),
  averaged over stratified points on the receiver.
* :func:`ray_first_hit` — the nearest parallelogram along camera rays.  Occlusion (the link
  attenuation factors V, §2.3) is :func:`nodes.common.rays.occluded`.

All lengths are in scene units (metres for builtin:cornell2); form factors are unitless.
Polygons are planar parallelograms given by origin o, edges u, v: x(s, t) = o + s·u + t·v,
s, t ∈ [0, 1], front normal n = u × v / |u × v|; or triangles (o, o + u, o + v): the same with
s + t ≤ 1, written as the 4 vertices (a, b, c, c) — the last two equal (:func:`is_triangle`).
"""
from __future__ import annotations

import functools

import numpy as np

from nodes.common.parallel import run_tasks
from nodes.common.rays import dual_basis  # noqa: F401  (in-plane coordinates, one place)


def is_triangle(verts: np.ndarray) -> np.ndarray:
    """(…,4,3) polygon vertices → (…) bool: a triangle (a, b, c, c), not a parallelogram."""
    return np.all(verts[..., 2, :] == verts[..., 3, :], axis=-1)


def frame(verts: np.ndarray):
    """(…,4,3) parallelogram or triangle vertices → origin, u, v, unit normal, area."""
    o = verts[..., 0, :]
    u = verts[..., 1, :] - o
    v = verts[..., 3, :] - o
    c = np.cross(u, v)
    area = np.linalg.norm(c, axis=-1)
    n = c / np.maximum(area, 1e-300)[..., None]
    return o, u, v, n, np.where(is_triangle(verts), 0.5, 1.0) * area


def corners(o, u, v, tri=None):
    """origin/edges (…,3) → the 4 vertices (…,4,3) in order o, o+u, o+u+v, o+v; where ``tri``
    (…) is True the triangle's (o, o+u, o+v, o+v)."""
    c = np.stack([o, o + u, o + u + v, o + v], axis=-2)
    if tri is not None and np.any(tri):
        c[..., 2, :] = np.where(np.asarray(tri)[..., None], o + v, c[..., 2, :])
    return c


def fold(st: np.ndarray, tri) -> np.ndarray:
    """Points (…,2) of the unit square → of the triangle s + t ≤ 1 where ``tri`` (…): a point
    past the diagonal is mirrored through (½, ½), so uniform (stratified) points stay so."""
    st = np.asarray(st, np.float64)
    out = np.where((st.sum(-1) > 1)[..., None], 1.0 - st, st)
    return np.where(np.asarray(tri)[..., None], out, st)


def grid_st(n: int) -> np.ndarray:
    """n×n stratified cell centres in [0,1]² → (n², 2)."""
    g = (np.arange(n) + 0.5) / n
    s, t = np.meshgrid(g, g, indexing="ij")
    return np.stack([s.ravel(), t.ravel()], 1)


def tri_st(n: int) -> np.ndarray:
    """The centroids of a triangle's n² equal sub-triangles (n per edge), in (s, t) with
    s + t ≤ 1 → (n², 2): an equal-weight midpoint rule, as :func:`grid_st` for the square."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    i, j = i.ravel(), j.ravel()
    up = i + j <= n - 1
    dn = i + j <= n - 2
    return np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], 1),
                           np.stack([i[dn] + 2 / 3, j[dn] + 2 / 3], 1)]) / n


def ff_point_polygon(x: np.ndarray, nx: np.ndarray, poly: np.ndarray,
                     chunk: int = 4096) -> np.ndarray:
    """Form factor from a differential area at x (normal nx) to a convex polygon (unoccluded).

    x, nx: (N,3); poly: (N,K,3) vertices in order.  The polygon is first clipped to the
    half-space in front of x (Sutherland–Hodgman), then Lambert's formula is applied:
    F = 1/(2π) Σ_k γ_k (R_k × R_{k+1})/|R_k × R_{k+1}| · nx, with γ_k the angle between the
    vectors R_k, R_{k+1} from x to consecutive vertices.  Returns (N,) unitless, ≥ 0.
    Points that see the whole polygon in front (most of them) skip the clipping.  Rows are
    independent; they are taken ``chunk`` at a time, on the cores (temporaries that stay in
    the cores' caches: on builtin:room's points 4096 at a time take ~25 % less CPU than 16k,
    which took 30 % less than 200k).
    """
    x = np.asarray(x, np.float64)
    nx = np.asarray(nx, np.float64)
    P = np.asarray(poly, np.float64)
    if len(x) > chunk:  # the chunks on the cores, joined in order (the same bits)
        return np.concatenate(run_tasks([functools.partial(ff_point_polygon, x[a:a + chunk],
                                                           nx[a:a + chunk], P[a:a + chunk])
                                         for a in range(0, len(x), chunk)]))
    R = np.ascontiguousarray(np.moveaxis(P - x[:, None, :], -1, 0))  # (3,N,K)
    nxt = np.ascontiguousarray(nx.T)[:, :, None]  # (3,N,1)
    d = (R * nxt).sum(0)
    whole = (d > 0).all(1)
    out = np.empty(len(x))
    if whole.all():
        return np.abs(_lambert(R, np.roll(R, -1, axis=2), nxt))
    if whole.any():
        Rw = R[:, whole]
        out[whole] = np.abs(_lambert(Rw, np.roll(Rw, -1, axis=2), nxt[:, whole]))
    clip = ~whole
    if clip.any():
        out[clip] = _ff_clipped(np.moveaxis(R[:, clip], 0, -1), d[clip], nx[clip])
    return out


def _lambert(V: np.ndarray, Vn: np.ndarray, nx: np.ndarray, pad: int = 0) -> np.ndarray:
    """Σ_k γ_k (V_k × V_k+1)/|V_k × V_k+1| · nx / 2π over the edges V_k → Vn_k, given
    component first: V, Vn (3,N,K), nx (3,N,1), and ``pad`` edges of length 0 after them
    (each term 0, summed in their places); K + pad a power of 2.
    γ_k = atan2(|V_k × V_k+1|, V_k · V_k+1).  Each product into one scratch array ``t``
    (few fresh temporaries; the same operations in the same order, so the same bits)."""
    (ax, ay, az), (bx, by, bz) = V, Vn
    t = np.empty_like(ax)
    cx = ay * bz
    cx -= np.multiply(az, by, out=t)
    cy = az * bx
    cy -= np.multiply(ax, bz, out=t)
    cz = ax * by
    cz -= np.multiply(ay, bx, out=t)
    cn = cx * cx
    cn += np.multiply(cy, cy, out=t)
    cn += np.multiply(cz, cz, out=t)
    np.sqrt(cn, out=cn)
    dot = ax * bx
    dot += np.multiply(ay, by, out=t)
    dot += np.multiply(az, bz, out=t)
    g = np.arctan2(cn, dot, out=dot)  # γ
    proj = np.multiply(cx, nx[0], out=cx)
    proj += np.multiply(cy, nx[1], out=t)
    proj += np.multiply(cz, nx[2], out=t)
    proj /= np.maximum(cn, 1e-300, out=t)
    g *= proj
    g[~(cn > 1e-300)] = 0.0
    if pad:
        g = np.concatenate([g, np.zeros((len(g), pad))], axis=1)
    while g.shape[1] > 1:  # pairwise, so the clipped path's 2K slots (every other edge of
        g = g[:, 0::2] + g[:, 1::2]  # length 0) give the same bits as the K edges
    return g[:, 0] / (2 * np.pi)


def _ff_clipped(R: np.ndarray, d: np.ndarray, nx: np.ndarray) -> np.ndarray:
    """Lambert's sum over the polygon R (N,K,3) (from the point) clipped to its part in
    front (d = R·nx > 0): each edge k → k+1 from its start, or where it comes in front, to
    its end, or where it goes behind (zero length when wholly behind), and the one edge the
    clip adds in the point's plane, from where the contour goes behind to where it comes
    back.  Summed as :func:`_lambert` sums 2K edges, so a polygon wholly in front gives the
    unclipped path's bits."""
    N, K, _ = R.shape
    R = np.moveaxis(R, -1, 0)  # (3,N,K)
    Rn = np.roll(R, -1, axis=2)
    dn = np.roll(d, -1, axis=1)
    front, front_n = d > 0, dn > 0
    cross_ = front != front_n
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(cross_, d / (d - dn), 0.0)
    inter = R + a * (Rn - R)  # where edge k crosses the plane (R_k where it does not)
    A = np.where(front, R, inter)
    B = np.where(front_n, Rn, inter)
    # a convex polygon's contour goes behind at most once and comes back once
    out_ = (inter * (front & ~front_n)).sum(2)
    in_ = (inter * (~front & front_n)).sum(2)
    V = np.concatenate([A, out_[..., None]], axis=2)
    Vn = np.concatenate([B, in_[..., None]], axis=2)
    return np.abs(_lambert(V, Vn, np.ascontiguousarray(nx.T)[:, :, None], pad=K - 1))


def element_form_factors(o_i, u_i, v_i, n_i, o_j, u_j, v_j, n_j, n_samples: int = 3,
                         chunk: int = 50_000, tri_i=None, tri_j=None) -> np.ndarray:
    """F_ij for M element pairs: receiver i, sender j (parallelograms, (M,3) each; triangles
    where ``tri_i`` / ``tri_j`` (M,) say so).

    F_ij = (1/A_i) ∫_{A_i} F_{dA→j} dA, by an n_samples² midpoint rule over i (folded into a
    triangle receiver: :func:`tri_st`) with the exact contour integral for the inner integral
    (so rows of a closed enclosure sum to 1 up to round-off).  Unitless.
    """
    M = len(o_i)
    st = grid_st(n_samples)
    S = len(st)
    out = np.zeros(M)
    P = corners(o_j, u_j, v_j, tri_j)
    step = max(1, chunk // S)
    for a in range(0, M, step):
        b = min(M, a + step)
        m = b - a
        sti = st[None] if tri_i is None else np.where(np.asarray(tri_i)[a:b, None, None],
                                                       tri_st(n_samples)[None], st[None])
        x = (o_i[a:b, None, :] + sti[..., 0:1] * u_i[a:b, None, :]
             + sti[..., 1:2] * v_i[a:b, None, :]).reshape(-1, 3)
        nx = np.repeat(n_i[a:b], S, axis=0)
        poly = np.repeat(P[a:b], S, axis=0)
        f = ff_point_polygon(x, nx, poly)
        # one-sided senders: points behind the sender's plane receive nothing
        front = np.einsum("nc,nc->n", x - np.repeat(o_j[a:b], S, axis=0),
                          np.repeat(n_j[a:b], S, axis=0)) > 0
        out[a:b] = np.where(front, f, 0.0).reshape(m, S).mean(1)
    return out


def ray_first_hit(o: np.ndarray, d: np.ndarray, occ_o, occ_u, occ_v, occ_n,
                  two_sided: bool = False, chunk: int = 1 << 21, tri=None):
    """Nearest parallelogram (or triangle, where ``tri`` (P,)) hit along rays o + t·d, t > 0.

    Returns (poly index or -1, t, s, tt) per ray; s, tt are the in-polygon coordinates.
    With ``two_sided=False`` only front faces (d·n < 0) are hit.
    """
    N = len(o)
    idx = np.full(N, -1)
    tb = np.full(N, np.inf)
    sb = np.zeros(N)
    ttb = np.zeros(N)
    if len(occ_o) == 0:
        return idx, tb, sb, ttb
    du, dv = dual_basis(occ_u, occ_v)
    step = max(1, chunk // len(occ_o))  # rays per block: ``chunk`` ray–polygon pairs
    for a in range(0, N, step):
        b = min(N, a + step)
        oo, dd = o[a:b], d[a:b]
        den = dd @ occ_n.T
        num = np.einsum("pc,pc->p", occ_o, occ_n)[None, :] - oo @ occ_n.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / den
        ok = (np.abs(den) > 1e-14) & (t > 1e-9)
        if not two_sided:
            ok &= den < 0
        q = oo[:, None, :] + np.where(ok, t, 0.0)[..., None] * dd[:, None, :] - occ_o[None]
        s = np.einsum("npc,pc->np", q, du)
        tt = np.einsum("npc,pc->np", q, dv)
        e = 1e-9
        hit = ok & (s >= -e) & (s <= 1 + e) & (tt >= -e) & (tt <= 1 + e)
        if tri is not None and np.any(tri):
            hit &= ~tri[None, :] | (s + tt <= 1 + e)
        tm = np.where(hit, t, np.inf)
        k = np.argmin(tm, axis=1)
        r = np.arange(b - a)
        has = np.isfinite(tm[r, k])
        idx[a:b] = np.where(has, k, -1)
        tb[a:b] = tm[r, k]
        sb[a:b] = np.clip(s[r, k], 0, 1)
        ttb[a:b] = np.clip(tt[r, k], 0, 1)
    return idx, tb, sb, ttb
