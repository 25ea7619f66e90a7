"""Soft shadows from a shadow map: percentage-closer soft shadows (Fernando 2005).

A light with a size (a sphere of radius R, or a disc of angular radius α seen from afar) casts
a penumbra whose width grows with the distance between the occluder and the receiver.  Per
receiver point, on the :class:`nodes.common.raster.ShadowMap` of the light's centre:

1. **blocker search**: the texels of the map that can hold an occluder between the point and
   some part of the light (the light's cone from the point, cut at the nearest depth in the
   map) are tapped; those nearer the light than the receiver are blockers, and the deepest of
   them (the nearest the receiver) gives the occluder's depth ``d_b``.  Fernando's *mean*
   blocker depth counts the front of a rounded occluder, whose edge is further back: it
   widened Mitsuba's penumbrae by 10–31 % on the tuning cases, the deepest blocker by +3…+20 %.
2. **penumbra estimate** by similar triangles, the half-width on the receiver at depth ``d_r``:
   ``R (d_r − d_b) / d_b`` (a sphere) or ``tan α (d_r − d_b)`` (a disc at infinity);
3. **percentage-closer filtering** over a *disc* of that radius: the lit fraction of a disc
   kernel across a straight occluder edge is the visible fraction of a disc light behind it,
   so the penumbra's profile (not only its width) follows the light's.

Taps follow one fixed Vogel (golden-angle) disc pattern; each filter tap is a bilinear
percentage-closer test (four texels weighted), so the result is smooth and deterministic (the
blocker search reads the nearest texel).  The
depth compared at a tap is the receiver's plane there (from its normal, receiver-plane depth
bias), so a large kernel does not shadow the receiver with itself.  Points with no blocker in
their search region are fully lit, and those whose every search tap is blocked are in the
umbra, both without filtering (the filter's disc lies inside the search's).

Checked against Mitsuba 3 (a sphere and a cone over a plane, spherical area lights): the
10–90 % penumbra width within 12 % of Mitsuba's on the five check cases;
``benchmarks/soft_shadow_reference.py`` and ``tests/test_soft_shadows.py``.
"""
from __future__ import annotations

import numpy as np

#: taps of the blocker search and of the filter (a Vogel disc each)
SEARCH_TAPS = 32
FILTER_TAPS = 64
#: the most texels a search or filter radius spans (bounds the cost of a huge light)
MAX_RADIUS = 96.0
#: points filtered at once (bounds the temporary memory: ~ CHUNK × FILTER_TAPS × 4 × 8 bytes)
CHUNK = 1 << 14
PAD = int(MAX_RADIUS) + 2  # texels of +inf round the map: no tap needs a bounds check


def vogel_disc(n: int) -> np.ndarray:
    """``n`` points spread evenly over the unit disc (golden-angle spiral), n×2."""
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n)
    t = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(t), r * np.sin(t)], 1)


def soft_visibility(sm, points: np.ndarray, normals: np.ndarray | None = None, *,
                    radius: float = 0.0, tan_angle: float = 0.0, bias: float = 1.5) -> np.ndarray:
    """Fraction (0…1) of a light with a size reaching each world point (N×3), from the shadow
    map ``sm`` of its centre (:func:`nodes.common.raster.shadow_map`).

    ``radius``: a point light's radius (world units); ``tan_angle``: the tangent of a
    directional light's angular radius.  ``bias`` in texels, as
    :meth:`~nodes.common.raster.ShadowMap.visibility`.
    """
    assert sm.complete, "soft shadows read the whole map (its nearest depth, a disc round each point)"
    pts = np.asarray(points, np.float64)
    out = np.ones(len(pts))
    good = np.flatnonzero(np.all(np.isfinite(pts), axis=1))
    finite = sm.depth[np.isfinite(sm.depth)]
    if len(good) == 0 or len(finite) == 0:
        return out
    z_near = float(finite.min())
    nrm = None if normals is None else np.asarray(normals, np.float64)
    dpad = np.pad(sm.depth, PAD, constant_values=np.inf)
    for s in range(0, len(good), CHUNK):
        idx = good[s:s + CHUNK]
        out[idx] = _chunk(sm, dpad, pts[idx], None if nrm is None else nrm[idx], radius,
                          tan_angle, bias, z_near)
    return out


def _chunk(sm, dpad, pts, nrm, radius, tan_angle, bias, z_near):
    """soft_visibility of finite points ``pts`` (one chunk), ``dpad`` the padded map."""
    xy, d = sm._project(pts)
    per_texel = sm.texel * (d / sm._ref_dist if sm.kind == "point" else np.ones(len(d)))  # world/texel at d
    grad = _receiver_gradient(sm, pts, nrm, per_texel)
    b = bias * per_texel * _slope_scale(sm, pts, nrm)
    if sm.kind == "point":  # the light's cone from the point, at the nearest depth, in texels
        search = radius * np.maximum(d - z_near, 0) / d * sm.scale[0] / z_near
    else:
        search = tan_angle * np.maximum(d - z_near, 0) / sm.texel
    search = np.clip(search, 1.0, MAX_RADIUS)
    blocked, deepest = _taps(dpad, xy, d - b, grad, search, vogel_disc(SEARCH_TAPS), bilinear=False)
    out = np.ones(len(pts))
    out[blocked > SEARCH_TAPS - 1e-6] = 0.0  # every search tap blocked: umbra (PCSS's early out)
    some = (blocked > 0) & (out > 0)
    if not some.any():
        return out
    d_b = deepest[some]
    ds = d[some]
    if sm.kind == "point":
        half = radius * (ds - d_b) / d_b * sm.scale[0] / ds
    else:
        half = tan_angle * (ds - d_b) / sm.texel
    half = np.clip(half, 1.0, MAX_RADIUS)
    shade, _ = _taps(dpad, xy[some], (d - b)[some], grad[some], half, vogel_disc(FILTER_TAPS))
    out[some] = np.clip(1.0 - shade / FILTER_TAPS, 0.0, 1.0)
    return out


def _slope_scale(sm, pts, nrm):
    """The bias's growth at grazing angles (as ShadowMap.visibility)."""
    if nrm is None:
        return 1.0
    cos = np.clip(np.abs((nrm * sm.light_dirs(pts)).sum(1)), 0.05, 1.0)
    return np.minimum(np.sqrt(1 - cos ** 2) / cos + 1.0, 10.0)


def _receiver_gradient(sm, pts, nrm, per_texel):
    """The receiver plane's depth change per texel along the map's x and y (N×2): 0 without
    normals; clamped at grazing angles."""
    if nrm is None:
        return np.zeros((len(pts), 2))
    n = nrm @ sm.to_light[:3, :3].T  # normals in the light frame
    nz = np.where(np.abs(n[:, 2]) < 0.2, np.copysign(0.2, n[:, 2]), n[:, 2])
    nz = np.where(nz == 0, 0.2, nz)
    return -n[:, :2] / nz[:, None] * per_texel[:, None]


def _taps(dpad, xy, d_test, grad, radius, disc, bilinear: bool = True):
    """Percentage-closer taps over a disc of ``radius`` texels round each point: bilinear
    (four texels weighted), or the nearest texel (the blocker search).

    Per point: (the weight of the taps where the map is nearer than the receiver plane (each
    tap weighs 1), the deepest of those taps' depths, −inf where none)."""
    H, W = dpad.shape[0] - 2 * PAD, dpad.shape[1] - 2 * PAD
    pad = PAD
    off = radius[:, None, None] * disc[None]  # N×T×2 texels
    ref = d_test[:, None] + (off * grad[:, None, :]).sum(2)  # the receiver plane at each tap
    u = np.clip(xy[:, None, 0] + off[..., 0] - 0.5, -pad + 1, W + pad - 2) + pad
    v = np.clip(xy[:, None, 1] + off[..., 1] - 0.5, -pad + 1, H + pad - 2) + pad
    if not bilinear:
        z = dpad[np.rint(v).astype(np.int64), np.rint(u).astype(np.int64)]
        blk = z < ref
        return blk.sum(1).astype(np.float64), np.where(blk, z, -np.inf).max(1)
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    hits = np.zeros(len(xy))
    deepest = np.full(len(xy), -np.inf)
    for du, dv, w in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)),
                      (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        z = dpad[v0 + dv, u0 + du]
        blk = w * (z < ref)
        hits += blk.sum(1)
        deepest = np.maximum(deepest, np.where(blk > 0, z, -np.inf).max(1))
    return hits, deepest


def is_sized(light) -> bool:
    """Does ``light`` have a size (a sphere or a disc: soft shadows, which read the whole map)?"""
    return light.radius_m > 0 or light.angular_radius_deg > 0


def light_visibility(sm, light, points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """Fraction of ``light`` (a :class:`graphkit.Light` in world units) reaching each point,
    from its shadow map ``sm``: the hard test with a 3×3 percentage-closer filter
    (:meth:`~nodes.common.raster.ShadowMap.visibility`) for a point or parallel light, soft
    shadows (:func:`soft_visibility`) for a light with a size."""
    if light.radius_m > 0:
        return soft_visibility(sm, points, normals, radius=light.radius_m)
    if light.angular_radius_deg > 0:
        return soft_visibility(sm, points, normals, tan_angle=float(np.tan(np.radians(light.angular_radius_deg))))
    return sm.visibility(points, normals)


def mesh_visibility(vertices: np.ndarray, faces: np.ndarray, light, size: int, points: np.ndarray,
                    normals: np.ndarray | None = None, up: np.ndarray | None = None) -> np.ndarray:
    """:func:`light_visibility` of world ``points`` on the ``size``² shadow map of the mesh
    seen from ``light`` (``up``: as :func:`~nodes.common.raster.shadow_map`).  For a light
    without a size only the texels the points' 3×3 taps read are rasterised (the same
    result as the whole map's, at the cost of the points' texels); soft shadows read the
    whole map."""
    from nodes.common.raster import shadow_map

    sm = shadow_map(vertices, faces, light, size, up=up, at=None if is_sized(light) else points)
    return light_visibility(sm, light, points, normals)
