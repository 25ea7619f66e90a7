"""Mitsuba 3 versions of a RoomScene: the photograph of builtin:cornell2 and test oracles.

Each parallelogram becomes a ``rectangle`` (one-sided diffuse BSDF, front = u × v); the
triangles (a, b, c, c) of one reflectance and light become one ``ply`` mesh (written to a
temporary folder kept for the process); emitters get an ``area`` emitter with radiance =
emittance / π.  Imported only by the data script and
the oracle tests (mitsuba is an optional, heavy import).
"""
from __future__ import annotations

import os

import numpy as np


def set_variant():
    import mitsuba as mi

    for v in ("scalar_rgb",):  # llvm_ad_rgb aborts in LLVM codegen on this machine
        try:
            mi.set_variant(v)
            return mi
        except Exception:  # noqa: BLE001 - try the next variant
            continue
    raise RuntimeError("no usable Mitsuba RGB variant")


def rect_to_world(verts: np.ndarray):
    """4×4 matrix taking Mitsuba's rectangle [-1,1]² (normal +z) onto the parallelogram."""
    o, u, w = verts[0], verts[1] - verts[0], verts[3] - verts[0]
    n = np.cross(u, w)
    n /= np.linalg.norm(n)
    M = np.eye(4)
    M[:3, 0] = u / 2
    M[:3, 1] = w / 2
    M[:3, 2] = n
    M[:3, 3] = o + (u + w) / 2
    return M


def tiles(verts: np.ndarray, n: int) -> np.ndarray:
    """Split a parallelogram into n×n tiles (s-major), (n²,4,3)."""
    o, u, w = verts[0], verts[1] - verts[0], verts[3] - verts[0]
    out = []
    for i in range(n):
        for j in range(n):
            a = o + (i / n) * u + (j / n) * w
            out.append([a, a + u / n, a + u / n + w / n, a + w / n])
    return np.array(out)


def scene_dict(scene, camera=None, spp: int = 64, emit_scale: dict | None = None,
               sensors_on: dict | None = None, max_depth: int = -1, width=None, height=None,
               fov_deg=None, lookat=None):
    """Mitsuba scene dict for a RoomScene.

    emit_scale: {light name: factor}; sensors_on: {polygon index: n} splits that polygon into
    n×n tiles carrying ``irradiancemeter`` sensors (named "irr_<poly>_<tile>").
    """
    mi = set_variant()
    T = mi.ScalarTransform4f
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": max_depth}}
    if lookat is not None:
        pos, tgt, up = lookat
        d["sensor"] = {"type": "perspective", "fov": fov_deg, "fov_axis": "x",
                       "to_world": T().look_at(origin=pos, target=tgt, up=up),
                       "sampler": {"type": "independent", "sample_count": spp},
                       "film": {"type": "hdrfilm", "width": width, "height": height,
                                "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
    emit_scale = emit_scale or {}
    sensors_on = sensors_on or {}
    from .geometry import is_triangle

    tri = is_triangle(scene.verts)
    tri[list(sensors_on)] = False
    groups = {}
    for p in np.flatnonzero(tri):
        key = (tuple(scene.reflectance[p]), scene.light[p], tuple(scene.emittance[p]))
        groups.setdefault(key, []).append(p)
    for g, (key, ps) in enumerate(groups.items()):
        p = ps[0]
        sh = {"type": "ply", "filename": _ply(scene.verts[ps, :3]), "face_normals": True,
              "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                          "value": list(key[0])}}}
        e = _radiance(scene, p, emit_scale)
        if e is not None:
            sh["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": e.tolist()}}
        d[f"tri{g}"] = sh
    for p, v in enumerate(scene.verts):
        if tri[p]:
            continue
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb",
                                                   "value": scene.reflectance[p].tolist()}}
        parts = tiles(v, sensors_on[p]) if p in sensors_on else [v]
        for k, tv in enumerate(parts):
            sh = {"type": "rectangle", "to_world": T(rect_to_world(tv).tolist()),
                  "bsdf": dict(bsdf, reflectance=dict(bsdf["reflectance"]))}
            e = _radiance(scene, p, emit_scale)
            if e is not None:
                sh["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": e.tolist()}}
            if p in sensors_on:
                sh[f"irr_{p}_{k}"] = {"type": "irradiancemeter",
                                "sampler": {"type": "independent", "sample_count": spp,
                                            "seed": 1000 * p + k},  # distinct: no dedup
                                "film": {"type": "hdrfilm", "width": 1, "height": 1,
                                         "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
            d[f"p{p}_{k}"] = sh
    return d


def _radiance(scene, p, emit_scale):
    """Polygon p's emitted radiance (emittance / π, scaled), or None if it emits nothing."""
    if not scene.light[p]:
        return None
    e = scene.emittance[p] * emit_scale.get(scene.light[p], 1.0) / np.pi
    return e if np.any(e > 0) else None


_TMP: list = []


def _ply(tris: np.ndarray) -> str:
    """Triangles (K,3,3) as a binary PLY in this process's temporary folder → its path."""
    import tempfile

    import trimesh

    if not _TMP:
        _TMP.append(tempfile.TemporaryDirectory(prefix="loscos-mitsuba-"))
    path = os.path.join(_TMP[0].name, f"t{len(os.listdir(_TMP[0].name))}.ply")
    V = np.asarray(tris, float).reshape(-1, 3)
    trimesh.Trimesh(V, np.arange(len(V)).reshape(-1, 3), process=False).export(path)
    return path


def render_photo(scene, lookat, fov_deg, width, height, spp, seed=0, emit_scale=None):
    """Linear-radiance RGB render (H,W,3) float32 from a look-at camera."""
    mi = set_variant()
    s = mi.load_dict(scene_dict(scene, spp=spp, emit_scale=emit_scale, width=width,
                                height=height, fov_deg=fov_deg, lookat=lookat))
    img = mi.render(s, spp=spp, seed=seed)
    return np.array(img, dtype=np.float32)[:, :, :3]


def irradiance(scene, sensors_on: dict, spp: int, seed=0):
    """{(poly, tile): RGB irradiance (W/m²)} from Mitsuba irradiancemeters on tiled polygons."""
    mi = set_variant()
    s = mi.load_dict(scene_dict(scene, spp=spp, sensors_on=sensors_on))
    out = {}
    for i, sen in enumerate(s.sensors()):
        _, p, k = sen.id().split("_")  # ids are irr_<poly>_<tile>; order is not guaranteed
        img = mi.render(s, sensor=sen, spp=spp, seed=seed + i)
        out[(int(p), int(k))] = np.array(img, dtype=np.float64).reshape(-1)[:3]
    return out


def tile_irradiance(scene, polys, n: int, res: int = 64, spp: int = 64, seed: int = 0):
    """{(poly, tile): RGB irradiance (W/m²)} on n×n tiles (s-major, as :func:`tiles`).

    Mitsuba's ``irradiancemeter`` samples cosine-weighted directions without emitter
    sampling, so a 0.17 m² light needs ~10⁶ samples per patch for 1 % noise.  Instead an
    ``orthographic`` sensor looks straight at each polygon from 1 mm in front of it; the path
    tracer (with emitter sampling) gives the exitant radiance L of the diffuse surface, and
    the irradiance is E = π L / ρ per channel, averaged over the pixels of each tile.
    """
    mi = set_variant()
    T = mi.ScalarTransform4f
    out = {}
    base = scene_dict(scene)
    for p in polys:
        v = scene.verts[p]
        o, u, w = v[0], v[1] - v[0], v[3] - v[0]
        nrm = np.cross(u, w); nrm /= np.linalg.norm(nrm)
        c = o + (u + w) / 2
        lu, lw = np.linalg.norm(u), np.linalg.norm(w)
        up = w / lw
        cam = (T().look_at(origin=(c + 1e-3 * nrm).tolist(), target=c.tolist(), up=up.tolist())
               @ T().scale([lu / 2, lw / 2, 1]))
        d = dict(base)
        d["sensor"] = {"type": "orthographic", "to_world": cam, "near_clip": 1e-4,
                       "sampler": {"type": "independent", "sample_count": spp},
                       "film": {"type": "hdrfilm", "width": res, "height": res,
                                "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
        img = np.array(mi.render(mi.load_dict(d), spp=spp, seed=seed + p), np.float64)[..., :3]
        # pixel (row, col) → local x = left = up × dir, image right is −x; image up is +y
        col = (np.arange(res) + 0.5) / res
        row = (np.arange(res) + 0.5) / res
        xl = -(2 * col - 1)  # local x (left) of each column
        yl = 1 - 2 * row  # local y (up) of each row
        dirv = -nrm
        left = np.cross(up, dirv)
        # world point = c + xl·left·lu/2 + yl·up·lw/2 → (s, t) along u, w
        Y, X = np.meshgrid(yl, xl, indexing="ij")
        P = c + X[..., None] * left * lu / 2 + Y[..., None] * up * lw / 2
        uu, ww, uw = u @ u, w @ w, u @ w
        det = uu * ww - uw * uw
        q = P - o
        s = (q @ u * ww - q @ w * uw) / det
        t = (q @ w * uu - q @ u * uw) / det
        i = np.clip((s * n).astype(int), 0, n - 1)
        j = np.clip((t * n).astype(int), 0, n - 1)
        E = np.pi * img / np.maximum(scene.reflectance[p], 1e-6)
        k = (i * n + j).ravel()
        for kk in range(n * n):
            out[(p, kk)] = E.reshape(-1, 3)[k == kk].mean(0)
    return out
