"""From per-leaf values to pixels (Loscos 2000 §4.4, eq. 3; Appendix A's per-vertex display).

The radiosity solution holds one value per leaf (the modulation T_final/T, B/D).  Drawn as
constant patches they show every leaf as a tile and every shadow edge as a staircase; the
paper draws the leaves with per-vertex colours (Gouraud).  Here a leaf value is spread to the
leaf's corners — each vertex takes the mean of the leaves of its polygon that touch it, one
vote per quarter around the vertex — and a point of the leaf takes the bilinear
interpolation of its four corners (:func:`interpolation`); a triangle leaf, the barycentric
interpolation of its three (one vote per triangle around the vertex).

Pixels that see more than one polygon (ProjectTextures' k×k subsamples) are drawn by
coverage.  The part of the pixel that sees an emitter is c; the photograph's pixel is
P = c·L_e + (1 − c)·S with L_e the emitter's radiance (its pure texels) and S the surround's
(the nearest pixels that see the surround alone), which gives c; the relit pixel is then
c·L_e' + (P − c·L_e)·r̄, with L_e' the emitter's new radiance and r̄ the surround's mean
modulation over the pixel's non-emitter subsamples.  Without this, pixels on the rim of a
light keep a bright outline when it is switched off (they took the ceiling's ratio).

:class:`PixelPlan` holds what does not depend on the emittances; :func:`modulate_pixels` is
Relight's whole per-pixel maths (one place, for other backends to follow).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .hierarchy import Hierarchy

LUM = np.array([0.2126, 0.7152, 0.0722])


@dataclass(eq=False)
class Interpolation:
    """Per-vertex interpolation of leaf values over a hierarchy's leaves.

    corner (L,4) vertex ids of each leaf's corners in the order (0,0), (1,0), (1,1), (0,1)
    (a triangle's o, o + u, o + v and o + v again, weighted 0);
    average (V × L) sparse, vertex value = mean of the leaves around it; grid/pos: leaf
    lookup (Hierarchy.leaf_grid) and element id → leaf position.
    """

    corner: np.ndarray
    average: object
    grid: np.ndarray
    pos: np.ndarray

    def weights(self, h: Hierarchy, poly, s, t):
        """Bilinear weights of sample points (poly, s, t): (vertex ids (m,4), weights (m,4))."""
        e = h.locate(poly, s, t, self.grid)
        k = self.pos[e]
        n = (1 << h.level[e]).astype(float)
        a = np.clip(s * n - h.ij[e, 0], 0, 1)
        b = np.clip(t * n - h.ij[e, 1], 0, 1)
        w = np.stack([(1 - a) * (1 - b), a * (1 - b), a * b, (1 - a) * b], 1)
        tri = h.tri(e)
        if tri.any():
            f = h.flipped[e][tri]
            at, bt = np.where(f, 1 - a[tri], a[tri]), np.where(f, 1 - b[tri], b[tri])
            wt = np.clip(np.stack([1 - at - bt, at, bt, np.zeros_like(at)], 1), 0, None)
            w[tri] = wt / wt.sum(1, keepdims=True)
        return self.corner[k], w


def interpolation(h: Hierarchy) -> Interpolation:
    """Vertices of the leaves of h (on each polygon's finest grid) and their averaging."""
    import scipy.sparse as sp

    lv = h.leaves
    top = int(h.level[lv].max())
    n = 1 << top
    n1 = n + 1
    b = 1 << (top - h.level[lv])
    X0, Y0 = h.ij[lv, 0] * b, h.ij[lv, 1] * b
    X = np.stack([X0, X0 + b, X0 + b, X0], 1)
    Y = np.stack([Y0, Y0, Y0 + b, Y0 + b], 1)
    tri = h.tri(lv)
    if tri.any():  # o, o + u, o + v, o + v (a flipped one from its cell's far corner)
        f = h.flipped[lv][tri][:, None]
        x0, y0, bb = X0[tri][:, None], Y0[tri][:, None], b[tri][:, None]
        X[tri] = np.where(f, x0 + bb - bb * np.array([0, 1, 0, 0]), x0 + bb * np.array([0, 1, 0, 0]))
        Y[tri] = np.where(f, y0 + bb - bb * np.array([0, 0, 1, 1]), y0 + bb * np.array([0, 0, 1, 1]))
    key = (h.poly[lv][:, None] * n1 + X) * n1 + Y
    uniq, corner = np.unique(key, return_inverse=True)
    corner = corner.reshape(-1, 4)
    vp, rest = np.divmod(uniq, n1 * n1)
    vx, vy = np.divmod(rest, n1)
    grid = h.leaf_grid(top)
    pos = np.full(h.n_elems, -1)
    pos[lv] = np.arange(len(lv))
    rows, cols = [], []
    vtri = h.tri_poly[vp]
    for dx in (-1, 0):
        for dy in (-1, 0):
            cx, cy = vx + dx, vy + dy
            ok = (cx >= 0) & (cx < n) & (cy >= 0) & (cy < n)
            # the cell's halves that touch the vertex (a parallelogram's are one leaf: one vote)
            halves = {(-1, -1): (1,), (0, 0): (0,)}.get((dx, dy), (0, 1))
            for k in halves:
                v = np.flatnonzero(ok & (vtri | (k == halves[0])))
                g = grid[vp[v], cx[v], cy[v], k]
                leaf = np.where(g >= 0, pos[g], -1)
                good = leaf >= 0
                rows.append(v[good])
                cols.append(leaf[good])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    cnt = np.bincount(rows, minlength=len(uniq)).astype(float)
    avg = sp.csr_matrix((1.0 / cnt[rows], (rows, cols)), shape=(len(uniq), len(lv)))
    return Interpolation(corner, avg, grid, pos)


@dataclass(eq=False)
class PixelPlan:
    """What drawing needs that does not depend on the emittances.

    index (n,) flat indices of the drawn pixels; base (n,3) the photograph's radiance there
    less the emitters' share; surface (n × L) sparse, the mean of the interpolated leaf
    values over the pixel's non-emitter samples; glow (n × L) sparse, the emitter coverage c
    times the mean interpolated leaf value over its emitter samples; coverage (n,) c.
    """

    photo: np.ndarray
    index: np.ndarray
    base: np.ndarray
    surface: object
    glow: object
    coverage: np.ndarray


def nearest_seen(h: Hierarchy, seen: np.ndarray) -> np.ndarray:
    """(L,) for each leaf of h: itself if ``seen``, else the nearest seen leaf of its polygon
    (centre to centre; itself when its polygon has none).  A leaf the camera does not see —
    under a box, or a strip along an edge whose texels all mix two polygons — has values the
    photograph never checked (T_final/T there can be 100 where H ≈ 0); drawn or averaged
    into a vertex it takes its nearest seen neighbour's."""
    from scipy.spatial import cKDTree

    lv = h.leaves
    c = h.centre(lv)
    out = np.arange(len(lv))
    for idx in polygon_groups(h.poly[lv]):
        on, off = idx[seen[idx]], idx[~seen[idx]]
        if len(on) and len(off):
            out[off] = on[cKDTree(c[on]).query(c[off])[1]]
    return out


def polygon_groups(poly: np.ndarray) -> list:
    """The indices of each polygon's entries of ``poly`` (ascending), polygon by polygon: one
    sort, so a loop over the polygons costs O(L log L), not O(P·L)."""
    order = np.argsort(poly, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(poly[order])) + 1) if len(poly) else []


def surround_radiance(photo: np.ndarray, pure: np.ndarray, sigma: float = 1.0):
    """Photo radiance seen by the nearest pure non-emitter pixels (normalised convolution
    with a Gaussian of ``sigma`` px); NaN where none is within about 3 px."""
    from scipy.ndimage import gaussian_filter

    w = pure.astype(float)
    den = gaussian_filter(w, sigma, mode="constant", truncate=3.0)
    out = np.stack([gaussian_filter(photo[..., c] * w, sigma, mode="constant", truncate=3.0)
                    for c in range(3)], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = out / den[..., None]
    out[den < 1e-3] = np.nan
    return out


def pixel_plan(h: Hierarchy, proj, photo: np.ndarray, emitter: np.ndarray, L_em: np.ndarray,
               interp: Interpolation | None = None, virtual=None,
               leaf_radiance: np.ndarray | None = None) -> PixelPlan:
    """Samples, weights and emitter coverage of every pixel that sees a polygon of h.

    emitter (P,) bool: polygons of lights; L_em (P,3): their radiance in the photograph.
    Surface samples: the pixel centre, or the non-emitter subsamples of a mixed pixel, each
    weighted by ``leaf_radiance`` (L,), the luminance of the leaf it falls on (NaN: unseen).
    Emitter part: the projection's exact coverage rows (em_*), the share c from the photo
    where a pixel mixes.  ``virtual`` (pixel, poly, cover, st) rows: polygons of h the
    photograph does not show (inserted), drawn over the rest by their coverage.
    """
    import scipy.sparse as sp

    interp = interp or interpolation(h)
    H, W = proj.pix_poly.shape
    photo = np.asarray(photo, np.float64).reshape(H * W, 3)
    pp = proj.pix_poly.reshape(-1)
    st = proj.pix_st.reshape(-1, 2)
    k2 = proj.sub_poly.shape[1]
    is_sub = np.zeros(H * W, bool)
    is_sub[proj.sub_pix] = True
    # surface samples (pixel, polygon, s, t)
    cen = np.flatnonzero((pp >= 0) & ~is_sub)
    f_pix = np.concatenate([cen, np.repeat(proj.sub_pix, k2)])
    f_poly = np.concatenate([pp[cen], proj.sub_poly.reshape(-1)])
    f_st = np.concatenate([st[cen], proj.sub_st.reshape(-1, 2)])
    m = f_poly >= 0
    m[m] &= ~emitter[f_poly[m]]
    f_pix, f_poly, f_st = f_pix[m], f_poly[m], f_st[m]
    # a mixed pixel's subsamples count by the radiance of the leaf they see (its mean texture
    # luminance): the pixel is Σ c_i L_i, so its modulation is Σ c_i L_i r_i / Σ c_i L_i — a
    # dark strip (the floor in a box's contact shadow, r large) moves it little
    f_w = np.ones(len(f_pix))
    if leaf_radiance is not None:
        lum = np.asarray(leaf_radiance, float)[interp.pos[h.locate(f_poly, f_st[:, 0],
                                                                   f_st[:, 1], interp.grid)]]
        f_w = np.where(np.isfinite(lum) & (lum > 0), lum, np.nan)
        mean = np.bincount(f_pix, np.nan_to_num(f_w), minlength=H * W) / np.maximum(
            np.bincount(f_pix, np.isfinite(f_w), minlength=H * W), 1)
        f_w = np.where(np.isfinite(f_w), f_w, mean[f_pix])  # unseen leaves: the pixel's mean
        f_w = np.where(f_w > 0, f_w, 1.0)
    # emitter samples with their share of the pixel (photographed ones, then inserted ones)
    if virtual is None:
        virtual = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)))
    v_pix, v_poly, v_cov, v_st = virtual
    index = np.unique(np.concatenate([f_pix, proj.em_pix, v_pix]))
    n = len(index)
    f_row = np.searchsorted(index, f_pix)
    g_row = np.searchsorted(index, proj.em_pix)
    v_row = np.searchsorted(index, v_pix)
    n_sf = np.bincount(f_row, minlength=n)
    c_geo = np.minimum(np.bincount(g_row, proj.em_cover, minlength=n), 1.0)
    c_virt = np.minimum(np.bincount(v_row, v_cov, minlength=n), 1.0)
    Le = np.zeros((n, 3))
    np.add.at(Le, g_row, proj.em_cover[:, None] * L_em[proj.em_poly])
    Le /= np.maximum(c_geo, 1e-12)[:, None]
    # emitter coverage c: 1 for pixels the emitters fill, from the photograph where they mix
    c = c_geo.copy()
    c[c_geo >= 1 - 1e-6] = 1.0
    P = photo[index]
    mix = (c_geo > 0) & (c_geo < 1 - 1e-6) & (n_sf > 0)
    if mix.any():
        pure = pp.copy()
        pure[proj.sub_pix] = -1
        pure[proj.em_pix] = -1
        pure = (pure >= 0) & ~emitter[np.maximum(pure, 0)]
        S = surround_radiance(photo.reshape(H, W, 3), pure.reshape(H, W)).reshape(-1, 3)
        S = S[index[mix]]
        d = Le[mix] - S
        den = np.einsum("nc,nc->n", d, d)
        cm = np.einsum("nc,nc->n", P[mix] - S, d) / np.maximum(den, 1e-300)
        good = np.isfinite(cm) & (den > 1e-12)
        c[mix] = np.clip(np.where(good, cm, c_geo[mix]), 0.0, 1.0)
    base = np.maximum(P - c[:, None] * Le, 0.0) * (1 - c_virt)[:, None]
    base[n_sf == 0] = 0.0
    V = interp.average.shape[0]

    def matrix(rows, poly, st_, weight):
        vid, w = interp.weights(h, poly, st_[:, 0], st_[:, 1])
        M = sp.csr_matrix(((w * weight[:, None]).reshape(-1), (np.repeat(rows, 4),
                                                             vid.reshape(-1))), shape=(n, V))
        return (M @ interp.average).tocsr()

    surface = matrix(f_row, f_poly, f_st, f_w / np.bincount(f_row, f_w, minlength=n)[f_row])
    share = c * (1 - c_virt) / np.maximum(c_geo, 1e-12)
    glow = matrix(np.concatenate([g_row, v_row]), np.concatenate([proj.em_poly, v_poly]),
                  np.concatenate([proj.em_st, v_st]),
                  np.concatenate([proj.em_cover * share[g_row], v_cov]))
    return PixelPlan(photo.reshape(H, W, 3).astype(np.float32), index,
                     base.astype(np.float32), surface, glow, c.astype(np.float32))


@dataclass(eq=False)
class PixelResponses:
    """Per drawn pixel and light: the surface modulation R and the emitted radiance G per
    unit emittance, so that an image for emittances e is base × R·e + G·e."""

    photo: np.ndarray  # (H,W,3) float32
    index: np.ndarray  # (n,) flat pixel indices
    base: np.ndarray  # (n,3) float32
    R: np.ndarray  # (S,n,3) float32
    G: np.ndarray  # (S,n,3) float32


def pixel_responses(plan: PixelPlan, surface_resp: np.ndarray, glow_resp: np.ndarray):
    """Apply the plan to per-leaf responses (L,S,3) → PixelResponses."""
    L, S, _ = surface_resp.shape
    R = plan.surface @ surface_resp.reshape(L, S * 3)
    G = plan.glow @ glow_resp.reshape(L, S * 3)
    n = len(plan.index)
    per_light = lambda M: np.ascontiguousarray(  # noqa: E731
        np.asarray(M).reshape(n, S, 3).transpose(1, 0, 2), np.float32)
    return PixelResponses(plan.photo, plan.index, plan.base, per_light(R), per_light(G))


def modulate_pixels(px: PixelResponses, e: np.ndarray) -> np.ndarray:
    """Relight's per-pixel maths (§4.4, eq. 3 per pixel, with emitters by coverage).

    For each drawn pixel p and channel c, with emittances e (S,3) in W/m²:
        out[p, c] = base[p, c] · Σ_s R[s, p, c] e[s, c]  +  Σ_s G[s, p, c] e[s, c]
    (base × interpolated modulation·B/D, plus the emitters' radiance times their coverage);
    every other pixel keeps the photograph.  Returns (H,W,3) float32 linear radiance.
    """
    e = np.asarray(e, np.float32)
    ratio = px.R[0] * e[0]
    glow = px.G[0] * e[0]
    for s in range(1, len(e)):
        ratio += px.R[s] * e[s]
        glow += px.G[s] * e[s]
    out = px.photo.copy()
    flat = out.reshape(-1, 3)
    flat[px.index] = px.base * ratio + glow
    return out
