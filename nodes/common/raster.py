"""A z-buffered triangle rasteriser in numpy, shared by every node that renders.

One implementation (CONTRIBUTING: one copy of each piece of maths).  It samples every pixel at
its centre (integer + 0.5, the :class:`graphkit.Camera` convention), keeps the nearest
triangle per pixel (z-buffer) and returns, per pixel, the camera-space depth, the coverage,
the triangle id and barycentric coordinates — **perspective-correct** (linear in 1/z) through a
perspective camera, affine (linear in screen space, which is exact there) through an
orthographic one — so any node can shade with :func:`interpolate`.  Projection goes through
:meth:`graphkit.Camera.project` (one implementation of the camera maths).  Shared edges follow a tie-breaking rule (a pixel centre exactly on
an edge shared by two triangles belongs to exactly one of them), so the covered pixel count of
a mesh equals its projected area up to boundary sampling.

Work is vectorised: per (triangle, row of its bounding box) the span of pixel centres allowed
by the three edge functions (scanline conversion), then per covered (triangle, pixel) pair the
barycentrics and depth, and a scatter-min z-buffer; in batches that bound the memory, with no
per-pixel Python loop.  Triangles with a vertex at or behind the camera's
near plane (z ≤ ``near``, both projections) are dropped (no clipping: the nodes refuse meshes
that cross the camera plane, ``nodes.paris.render.check_in_view``).

Shadow maps (Williams 1978, used by Paris 2003 §5 "Cast shadows") are built on the same
rasteriser: :func:`shadow_map` renders depth from a directional (orthographic) or point
(perspective) light and :meth:`ShadowMap.visibility` tests points against it with a slope
bias and percentage-closer filtering; :mod:`nodes.common.shadows` filters the same map to the
penumbra of a light with a size (percentage-closer soft shadows).

Units: whatever the mesh uses (depth is in mesh units along the camera's +z axis).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: candidate (triangle, pixel) pairs evaluated at once; bounds the temporary memory (~100 B each)
BATCH_PAIRS = 1 << 21


@dataclass
class Raster:
    """Per-pixel result of :func:`rasterize` (H×W arrays)."""

    depth: np.ndarray  # float64, camera-space z (inf where uncovered)
    coverage: np.ndarray  # bool
    tri: np.ndarray  # int64 triangle index, -1 where uncovered
    bary: np.ndarray  # float64 H×W×3 perspective-correct barycentrics (0 where uncovered)

    @property
    def shape(self) -> tuple[int, int]:
        return self.coverage.shape


#: the near limit of camera views (camera-frame z, world units): triangles with a vertex at or
#: in front of it are dropped
NEAR = 1e-6


def project_vertices(vertices: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """World vertices → (pixel xy N×2, camera-space z N) with a :class:`graphkit.Camera`."""
    xy, z = camera.project(np.asarray(vertices, np.float64))
    return xy, z


def rasterize(vertices: np.ndarray, faces: np.ndarray, camera, *, cull: str = "none",
              near: float = NEAR) -> Raster:
    """Rasterise a triangle mesh (world coordinates) through a perspective or orthographic
    ``camera`` (:class:`graphkit.Camera`).

    ``cull``: "none", "back" (drop triangles seen from behind, counter-clockwise = front in
    OpenCV image axes for outward-facing, right-handed meshes) or "front".
    """
    xy, z = project_vertices(vertices, camera)
    return rasterize_screen(xy, z, faces, camera.width, camera.height,
                            perspective=not camera.orthographic, cull=cull, near=near)


def rasterize_screen(xy: np.ndarray, z: np.ndarray, faces: np.ndarray, width: int, height: int,
                     *, perspective: bool = True, cull: str = "none",
                     near: float | None = NEAR, depth_only: bool = False,
                     want: np.ndarray | None = None) -> Raster:
    """Rasterise triangles given vertex screen positions (pixels) and depths.

    With ``perspective`` the barycentrics and depth are interpolated perspective-correctly
    (linear in 1/z); without it (orthographic views) linearly in screen space.  Triangles with
    a vertex at z ≤ ``near`` are dropped (``near=None``: none, e.g. orthographic light views).
    ``depth_only`` (shadow maps): only the depth is resolved; the triangle ids, coverage and
    barycentrics are left empty.  ``want`` (with ``depth_only``): which tiles of TILE² pixels
    are wanted (a ⌈H/TILE⌉×⌈W/TILE⌉ bool mask): only the triangles whose pixel box meets one
    are drawn, so the pixels of those tiles get the depths of the whole z-buffer (the same
    arithmetic, bit for bit) and others may be left +inf.
    """
    xy = np.asarray(xy, np.float64)
    z = np.asarray(z, np.float64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    H, W = int(height), int(width)
    depth = np.full(H * W, np.inf)
    if depth_only:  # read-only views of one value, no memory: only the depth is resolved
        tri, bary = np.broadcast_to(np.int64(-1), (H * W,)), np.broadcast_to(0.0, (H * W, 3))
    else:
        tri, bary = np.full(H * W, -1, np.int64), np.zeros((H * W, 3))
    if len(faces) == 0:
        return Raster(depth.reshape(H, W), tri.reshape(H, W) >= 0, tri.reshape(H, W),
                      bary.reshape(H, W, 3))

    fz = z[faces]  # F×3
    good = np.isfinite(xy).all(1) & np.isfinite(z)  # per vertex, then per face (every vertex)
    if near is not None:
        good &= z > near
    ok = good[faces[:, 0]] & good[faces[:, 1]] & good[faces[:, 2]]
    # the corners' coordinates, one contiguous array each (x0 = the first corners' x, …)
    X = [xy[:, 0][faces[:, j]] for j in range(3)]
    Y = [xy[:, 1][faces[:, j]] for j in range(3)]
    (x0, x1, x2), (y0, y1, y2) = X, Y
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)  # >0: clockwise on screen (y down)
    ok &= area != 0
    if cull == "back":
        ok &= area < 0
    elif cull == "front":
        ok &= area > 0
    # pixel index range whose centres (i + 0.5) may fall inside the triangle
    with np.errstate(invalid="ignore"):
        # (element-wise over the three vertices: a reduction along an axis of 3 is ~20× slower)
        xmin = np.maximum(np.ceil(np.minimum(np.minimum(x0, x1), x2) - 0.5), 0)
        xmax = np.minimum(np.floor(np.maximum(np.maximum(x0, x1), x2) - 0.5), W - 1)
        ymin = np.maximum(np.ceil(np.minimum(np.minimum(y0, y1), y2) - 0.5), 0)
        ymax = np.minimum(np.floor(np.maximum(np.maximum(y0, y1), y2) - 0.5), H - 1)
    ok &= (xmax >= xmin) & (ymax >= ymin)
    if want is not None:
        ok &= _boxes_meet(want, ok, xmin, xmax, ymin, ymax)
    ids = np.nonzero(ok)[0]
    if len(ids) == 0:
        return Raster(depth.reshape(H, W), tri.reshape(H, W) >= 0, tri.reshape(H, W),
                      bary.reshape(H, W, 3))
    bw = (xmax[ids] - xmin[ids] + 1).astype(np.int64)
    bh = (ymax[ids] - ymin[ids] + 1).astype(np.int64)
    npix = bw * bh
    # batches of triangles with at most BATCH_PAIRS candidate pixels (a single huge triangle
    # forms its own batch)
    csum = np.cumsum(npix)
    starts = [0]
    while starts[-1] < len(ids):
        base = csum[starts[-1] - 1] if starts[-1] else 0
        nxt = int(np.searchsorted(csum, base + BATCH_PAIRS, side="right"))
        starts.append(max(nxt, starts[-1] + 1))
    # edge functions e_i = A_i x + B_i y + C_i (weight of vertex i), positive inside, and the
    # tie rule per edge; computed once per triangle
    sg = np.sign(area)
    A, B, C = [], [], []
    own = np.empty((len(faces), 3), bool)
    for i in range(3):
        (ax, ay), (bx, by) = ((X[j], Y[j]) for j in ((i + 1) % 3, (i + 2) % 3))
        A.append(-(by - ay) * sg)
        B.append((bx - ax) * sg)
        C.append(((by - ay) * ax - (bx - ax) * ay) * sg)
        own[:, i] = _owns_edge(ax, ay, bx, by, sg)
    for a, b in zip(starts[:-1], starts[1:]):
        rows = _row_spans(ids[a:b], bh[a:b], xmin, xmax, ymin, A, B, C, own)
        if depth_only:
            _depth_rows(*rows, A, B, C, fz, area, perspective, W, depth)
        else:
            _resolve(*_pixels(*rows), A, B, C, fz, area, perspective, W, depth, (tri, bary))
    cov = np.broadcast_to(False, (H * W,)) if depth_only else tri >= 0  # (no ids: none covered)
    return Raster(depth.reshape(H, W), cov.reshape(H, W), tri.reshape(H, W),
                  bary.reshape(H, W, 3))


#: the side of the tiles of ``rasterize_screen``'s ``want``
TILE = 8


def _boxes_meet(want, ok, xmin, xmax, ymin, ymax):
    """Per triangle: does its pixel box [xmin, xmax] × [ymin, ymax] meet a wanted tile of TILE²
    pixels (``want``)?  False where not ``ok``."""
    sat = np.zeros((want.shape[0] + 1, want.shape[1] + 1), np.int64)  # summed-area table:
    sat[1:, 1:] = want
    sat = sat.cumsum(0).cumsum(1)  # sat[i, j] = the wanted tiles above and left of (i, j)
    k = np.flatnonzero(ok)
    y0, y1 = ymin[k].astype(np.int64) // TILE, ymax[k].astype(np.int64) // TILE + 1
    x0, x1 = xmin[k].astype(np.int64) // TILE, xmax[k].astype(np.int64) // TILE + 1
    out = np.zeros(len(ok), bool)
    out[k] = sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0] > 0
    return out


def _owns_edge(ax, ay, bx, by, sign):
    """Tie rule for a pixel centre exactly on edge a→b (of a triangle with orientation sign).

    Antisymmetric under reversing the edge, so of two consistently oriented triangles sharing
    the edge exactly one owns the pixel."""
    dx, dy = (bx - ax) * sign, (by - ay) * sign
    return (dy > 0) | ((dy == 0) & (dx < 0))


def _row_spans(ids, bh, xmin, xmax, ymin, A, B, C, own):
    """Per (triangle, row of its bounding box): (the triangle, the row's centre y + 0.5, the
    first pixel index whose centre is inside the triangle, how many are): the span allowed by
    the three edge functions (scanline conversion)."""
    R = int(bh.sum())
    t = np.repeat(ids, bh)
    yc = np.arange(R) - np.repeat(np.cumsum(bh) - bh - ymin[ids], bh) + 0.5
    lo = np.repeat(xmin[ids], bh)  # first allowed pixel index
    hi = np.repeat(xmax[ids], bh)  # last allowed pixel index
    dead = np.zeros(R, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            a, o = A[i][ids], own[ids, i]
            c = np.repeat(B[i][ids], bh) * yc + np.repeat(C[i][ids], bh)
            # the edge crosses the row at pixel index `bound` = −c/a − 0.5; a > 0: x ≥ bound,
            # a < 0: x ≤ bound (inclusive when the edge is owned, else strict).  `b` is ±bound
            # (exactly), so that both are one ceiling: the first allowed index, or minus the last
            b = c / np.repeat(-np.abs(a), bh) + np.repeat(-0.5 * np.sign(a), bh)
            cb = np.ceil(b)
            first = cb + ((b == cb) & np.repeat(~o, bh))
            lo = np.maximum(lo, np.where(np.repeat(a > 0, bh), first, -np.inf))
            hi = np.minimum(hi, np.where(np.repeat(a < 0, bh), -first, np.inf))
            if (a == 0).any():  # a row beside a horizontal edge's inside has no pixel
                dead |= np.repeat(a == 0, bh) & ((c < 0) | ((c == 0) & np.repeat(~o, bh)))
    return t, yc, lo, np.where(dead, 0, np.maximum(hi - lo + 1, 0)).astype(np.int64)


def _pixels(t, yc, lo, n):
    """The pixels (triangle, x + 0.5, y + 0.5) of :func:`_row_spans`' spans."""
    row = np.repeat(np.arange(len(t)), n)
    px = lo[row] + _offsets(n) + 0.5
    return t[row], px, yc[row]


def _offsets(n):
    """0, 1, …, n[0] − 1, 0, 1, …, n[1] − 1, …: each pixel's place in its span."""
    return np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)


def _depth_rows(t, yc, lo, n, A, B, C, fz, area, perspective, W, depth):
    """The z-buffer (scatter-min) of the spans' depths, without barycentrics (shadow maps):
    the depth (orthographic) or its inverse (perspective) is linear along a row, so it is
    interpolated from the edge functions at each span's first pixel (as :func:`_resolve`) and
    stepped across the span: the full path's depths to ~1e-12 (tests/test_raster.py)."""
    keep = n > 0
    t, yc, lo, n = t[keep], yc[keep], lo[keep], n[keep]
    if len(t) == 0:
        return
    x = lo + 0.5
    Z = fz[t] if not perspective else 1.0 / fz[t]
    absa = np.abs(area[t])
    e = [A[i][t] * x + B[i][t] * yc + C[i][t] for i in range(3)]
    z0 = e[0] / absa * Z[:, 0] + e[1] / absa * Z[:, 1] + e[2] / absa * Z[:, 2]
    dz = (A[0][t] * Z[:, 0] + A[1][t] * Z[:, 1] + A[2][t] * Z[:, 2]) / absa  # per pixel along x
    k = _offsets(n)
    zk = np.repeat(z0, n) + k * np.repeat(dz, n)
    if perspective:
        zk = 1.0 / zk
    pix = np.repeat((yc - 0.5).astype(np.int64) * W + lo.astype(np.int64), n) + k
    np.minimum.at(depth, pix, zk)


def _resolve(t, px, py, A, B, C, fz, area, perspective, W, depth, ids):
    """Barycentrics, depth and the z-buffer test of inside pixels; the winners' triangle ids
    and barycentrics into ``ids`` = (tri, bary)."""
    if len(t) == 0:
        return
    e0, e1, e2 = (A[i][t] * px + B[i][t] * py + C[i][t] for i in range(3))
    pix = (py - 0.5).astype(np.int64) * W + (px - 0.5).astype(np.int64)
    absa = np.abs(area[t])
    b = np.stack([e0, e1, e2], 1) / absa[:, None]  # screen-space barycentrics
    Z = fz[t]
    if perspective:
        bz = b / Z
        inv = bz.sum(1)
        zk = 1.0 / inv
        b = bz * zk[:, None]
    else:
        zk = (b * Z).sum(1)
    # z-buffer: scatter-min of the depths, then the winners (ties: lowest triangle id)
    np.minimum.at(depth, pix, zk)
    tri, bary = ids
    wi = np.nonzero(zk == depth[pix])[0]
    tk = t[wi]
    best = np.full(len(depth), np.iinfo(np.int64).max)
    np.minimum.at(best, pix[wi], tk)
    sel = wi[tk == best[pix[wi]]]
    pp = pix[sel]
    tri[pp] = t[sel]
    bary[pp] = b[sel]


def interpolate(r: Raster, faces: np.ndarray, attr: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Per-vertex attribute (N×C or N) → per-pixel values (H×W×C or H×W), perspective-correct."""
    attr = np.asarray(attr)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    squeeze = attr.ndim == 1
    a = attr[:, None] if squeeze else attr
    H, W = r.shape
    out = np.full((H, W, a.shape[1]), fill, dtype=np.float64)
    cov = r.coverage
    f = faces[r.tri[cov]]  # M×3
    b = r.bary[cov]  # M×3
    out[cov] = (a[f] * b[..., None]).sum(1)
    return out[..., 0] if squeeze else out


def world_points(r: Raster, faces: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """World position of the visible surface at each pixel (H×W×3; NaN where uncovered)."""
    return interpolate(r, faces, np.asarray(vertices, np.float64), fill=np.nan)


# ----------------------------------------------------------------------------------------------
# shadow maps


@dataclass
class ShadowMap:
    """Depth of the nearest surface seen from a light (Williams 1978).

    ``kind`` "directional": orthographic along ``-direction``; "point": perspective from
    ``position``.  ``to_light`` is the 4×4 world → light-view matrix (OpenCV axes, +z away
    from the light), ``scale``/``offset`` map light-view coordinates to shadow-map pixels.
    """

    kind: str
    depth: np.ndarray
    to_light: np.ndarray
    scale: np.ndarray  # (sx, sy): pixels per unit (ortho) or focal lengths (point)
    offset: np.ndarray  # (ox, oy) pixels
    texel: float  # world size of one texel at the mesh (for the bias)

    def _project(self, pts):
        q = pts @ self.to_light[:3, :3].T + self.to_light[:3, 3]
        if self.kind == "directional":
            xy = q[:, :2] * self.scale + self.offset
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                xy = q[:, :2] / q[:, 2:3] * self.scale + self.offset
        return xy, q[:, 2]

    def visibility(self, points: np.ndarray, normals: np.ndarray | None = None,
                   bias: float = 1.5, pcf: int = 1) -> np.ndarray:
        """Fraction (0…1) of the light reaching each world point (N×3).

        ``bias`` is in shadow-map texels (scaled up at grazing angles when ``normals`` are
        given); ``pcf`` is the half-width of the percentage-closer filter (1 → 3×3 taps).
        """
        pts = np.asarray(points, np.float64)
        out = np.ones(len(pts))
        good = np.all(np.isfinite(pts), axis=1)
        if not good.any():
            return out
        pts = pts[good]
        xy, d = self._project(pts)
        b = np.full(len(pts), bias * self.texel)
        if normals is not None:
            n = np.asarray(normals, np.float64)[good]
            ldir = self.light_dirs(pts)
            cos = np.clip(np.abs(n[:, 0] * ldir[:, 0] + n[:, 1] * ldir[:, 1] + n[:, 2] * ldir[:, 2]), 0.05, 1.0)
            b = b * np.minimum(np.sqrt(1 - cos ** 2) / cos + 1.0, 10.0)
        if self.kind == "point":
            b = b * np.maximum(d, 1e-9) / self._ref_dist
        H, W = self.depth.shape
        ix, iy = _tap_centres(xy, W, H)
        # the map's block under the taps, padded with +inf (nothing in the way) so that the
        # taps need no bounds checks
        p = pcf + 1
        x0, y0 = max(int(ix.min()) - pcf, 0), max(int(iy.min()) - pcf, 0)
        x1, y1 = min(int(ix.max()) + p, W), min(int(iy.max()) + p, H)
        dpad = np.pad(self.depth[y0:y1, x0:x1], p, constant_values=np.inf)
        Wp = dpad.shape[1]
        dpad = dpad.ravel()
        base = (iy - y0 + p) * Wp + ix - x0 + p
        db = d - b
        acc = np.zeros(len(pts))
        taps = 0
        for dy in range(-pcf, pcf + 1):
            for dx in range(-pcf, pcf + 1):
                acc += db <= dpad[base + (dy * Wp + dx)]
                taps += 1
        out[good] = acc / taps
        return out

    def tap_tiles(self, points: np.ndarray, pcf: int = 1) -> np.ndarray:
        """Which tiles of TILE² texels (``rasterize_screen``'s ``want``) hold the texels that
        :meth:`visibility` reads for ``points`` with ``pcf`` (< TILE)."""
        pts = np.asarray(points, np.float64)
        H, W = self.depth.shape
        ix, iy = _tap_centres(self._project(pts[np.all(np.isfinite(pts), axis=1)])[0], W, H)
        tiles = np.zeros((-(-H // TILE), -(-W // TILE)), bool)
        for y in (iy - pcf, iy + pcf):  # a tap square smaller than a tile: its corners' tiles
            for x in (ix - pcf, ix + pcf):
                tiles[np.clip(y, 0, H - 1) // TILE, np.clip(x, 0, W - 1) // TILE] = True
        return tiles

    def light_dirs(self, pts: np.ndarray) -> np.ndarray:
        """Unit directions from points towards the light."""
        inv = np.linalg.inv(self.to_light)
        if self.kind == "directional":
            d = -inv[:3, 2]
            return np.broadcast_to(d / np.linalg.norm(d), pts.shape)
        v = inv[:3, 3] - pts
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    _ref_dist: float = 1.0
    #: False for a map made only at some points' taps (shadow_map's ``at``): read it there only
    complete: bool = True


def _tap_centres(xy: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """The texel (x, y) a point's percentage-closer taps centre on, clipped to the map and the
    ring of texels round it (−1 … W, −1 … H)."""
    ix = np.clip(np.floor(xy[:, 0]), -1, W).astype(np.int64)
    iy = np.clip(np.floor(xy[:, 1]), -1, H).astype(np.int64)
    return ix, iy


def _look_frame(forward: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """3×3 rotation whose rows are the light-view x, y, z axes (z = forward).  ``up`` (world)
    orients the texel grid (e.g. the viewing camera's y axis, so that the map is laid out the
    same way whatever the world's axes); world y by default."""
    f = forward / np.linalg.norm(forward)
    if up is not None:
        up = np.asarray(up, np.float64)
        if np.linalg.norm(np.cross(up, f)) < 0.1 * np.linalg.norm(up):
            up = None
    if up is None:
        up = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, f)
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    return np.stack([x, y, f])


@dataclass
class ShadowFrame:
    """Where a shadow map looks from: the light frame and its projection onto ``size``² texels.

    ``M`` maps world → light frame (z away from the light), ``q`` holds the vertices in that
    frame; a light-frame point p lands on texel ``p.xy * scale + offset`` (orthographic) or
    ``p.xy / p.z * scale + offset`` (perspective).  ``texel`` is the world size of one texel
    (at distance ``ref_dist`` for point lights), used for the depth bias.
    """

    kind: str
    M: np.ndarray
    q: np.ndarray
    scale: np.ndarray
    offset: np.ndarray
    texel: float
    ref_dist: float
    perspective: bool


def shadow_frame(vertices: np.ndarray, light, size: int = 512, margin: float = 0.02,
                 up: np.ndarray | None = None) -> ShadowFrame:
    """The frame of a shadow map of ``vertices`` seen from ``light`` (see :func:`shadow_map`;
    ``up``: the world direction the texel grid's y axis follows, e.g. the camera's y).

    Shared by every rasteriser that renders shadow maps (the numpy one here, the OpenGL backend).
    """
    V = np.asarray(vertices, np.float64)
    if light.kind == "directional":
        R = _look_frame(-np.asarray(light.direction, np.float64), up)
        q = V @ R.T
        lo, hi = q[:, :2].min(0), q[:, :2].max(0)
        ext = float(max(hi - lo)) * (1 + 2 * margin) or 1.0
        M = np.eye(4)
        M[:3, :3] = R
        scale = np.array([size / ext, size / ext])
        offset = size / 2 - (lo + hi) / 2 * scale
        return ShadowFrame("directional", M, q, scale, offset, ext / size, 1.0, False)
    pos = np.asarray(light.position, np.float64)
    c = V.mean(0)
    R = _look_frame(c - pos, up)
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ pos
    q = V @ R.T + M[:3, 3]
    if np.any(q[:, 2] <= 1e-9):
        raise ValueError("point light inside or in front of the mesh's bounds: no shadow map")
    t = np.abs(q[:, :2] / q[:, 2:3]).max() * (1 + 2 * margin)
    f = size / (2 * t)
    dref = float(np.linalg.norm(c - pos))
    return ShadowFrame("point", M, q, np.array([f, f]), np.array([size / 2, size / 2]), dref / f, dref, True)


def shadow_map(vertices: np.ndarray, faces: np.ndarray, light, size: int = 512,
               margin: float = 0.02, up: np.ndarray | None = None, at: np.ndarray | None = None,
               pcf: int = 1) -> ShadowMap:
    """Render the depth of a mesh seen from ``light`` (a :class:`graphkit.Light`).

    Directional lights use an orthographic view fitted to the mesh's bounds; point lights a
    perspective view from the light's position whose field of view fits the mesh.
    ``at`` (N×3 world points): the map will only be read by :meth:`ShadowMap.visibility` at
    those points with ``pcf`` (< TILE), so only the triangles that meet the tiles of the
    texels it reads there are drawn (those texels' depths are the whole map's, bit for bit;
    texels elsewhere may stay +inf, ``complete`` False): a few points cost their part of the
    map, not all of it.
    """
    fr = shadow_frame(vertices, light, size, margin, up)
    sm = ShadowMap(fr.kind, np.broadcast_to(np.inf, (size, size)), fr.M, fr.scale, fr.offset, fr.texel)
    if fr.perspective:
        sm._ref_dist = fr.ref_dist
    want = None
    if at is not None:
        want, sm.complete = sm.tap_tiles(at, pcf), False
    xy = fr.q[:, :2] / fr.q[:, 2:3] if fr.perspective else fr.q[:, :2]
    sm.depth = rasterize_screen(xy * fr.scale + fr.offset, fr.q[:, 2], faces, size, size,
                                perspective=fr.perspective, near=NEAR if fr.perspective else None,
                                depth_only=True, want=want).depth
    return sm


def edge_coverage(xy: np.ndarray, faces: np.ndarray, coverage: np.ndarray,
                  step: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Fractional coverage of the pixels along a mesh's silhouette (anti-aliasing), from the
    binary ``coverage`` of :func:`rasterize` and the vertices' screen positions ``xy``.

    The silhouette is the mesh's boundary edges and its contour edges (the two triangles on
    either side face opposite ways on screen) that lie next to a coverage change; each pixel
    with a 4-neighbour of the other coverage gets 0.5 ± the distance from its centre to the
    nearest such edge (+ covered, − not), clipped to [0, 1]: a box filter across a straight
    edge.  Other pixels keep 0 or 1.  Returns (the H×W float32 coverage, for every pixel the
    flat index of the nearest covered pixel: where an uncovered pixel takes its colour from)."""
    import cv2
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import cKDTree

    cov = np.asarray(coverage, bool)
    frac = cov.astype(np.float32)
    _, (iy, ix) = distance_transform_edt(~cov, return_indices=True)
    src = (iy * cov.shape[1] + ix).ravel()
    u8 = cov.astype(np.uint8)
    k = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    band = cv2.dilate(u8, k) != cv2.erode(u8, k)
    seg = _silhouette_edges(np.asarray(xy, np.float64), np.asarray(faces, np.int64).reshape(-1, 3))
    if not band.any() or len(seg) == 0:
        return frac, src
    near = cv2.dilate(band.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    mid = np.floor(seg.mean(1)).astype(np.int64)
    H, W = cov.shape
    inside = (mid[:, 0] >= 0) & (mid[:, 0] < W) & (mid[:, 1] >= 0) & (mid[:, 1] < H)
    seg = seg[inside]
    seg = seg[near[mid[inside, 1], mid[inside, 0]]]
    if len(seg) == 0:
        return frac, src
    n = np.maximum(np.ceil(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1) / step), 1).astype(np.int64)
    t = np.concatenate([np.arange(m + 1) / m for m in n])
    s = np.repeat(np.arange(len(seg)), n + 1)
    pts = seg[s, 0] + (seg[s, 1] - seg[s, 0]) * t[:, None]
    by, bx = np.nonzero(band)
    d, _ = cKDTree(pts).query(np.stack([bx + 0.5, by + 0.5], 1))
    frac[by, bx] = np.clip(0.5 + np.where(cov[by, bx], d, -d), 0.0, 1.0)
    return frac, src


def _silhouette_edges(xy: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The screen segments (K×2×2) of the mesh's boundary edges and contour edges (the two
    faces on either side wound opposite ways on screen); degenerate faces are left out."""
    p = xy[faces]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    keep = np.isfinite(area) & (area != 0)
    f, sg = faces[keep], np.sign(area[keep])
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    es = np.concatenate([sg, sg, sg])
    key = np.sort(e, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    pos = np.zeros(len(cnt))
    np.add.at(pos, inv, es > 0)
    sil = (cnt == 1) | ((pos > 0) & (pos < cnt))  # boundary, or faces of both windings
    first = np.full(len(cnt), -1, np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    return xy[e[first[sil]]]
