"""Run the Paris 2003 pipeline on one capture of ``make_capture_set`` and measure it against
Mitsuba (used by benchmarks/bench_paris_captures.py and tests/oracles/test_paris_face_mitsuba.py).

Pipeline, with the graph nodes called directly: ProbeLight (ball centre/radius from the
scene's truth — the automatic ball finding is another issue's work —, flash offset, ball and
face positions, the probe camera) → ReflectanceMap (skin samples, the flash's fall-off divided
out) → ShininessFromSaturation (the photo's own pixels and camera) → ShadeFace → RatioImage (the detail
texture) → FitSkinPhong → Render under each relight with the detail texture.

Measure: PSNR (peak 1) between Render and Mitsuba's render under the same light (same ambient,
no flash) on the skin (the truth skin mask less the silhouette ring), with the pixels in a
cast shadow (Mitsuba ray tests towards the light) counted apart ("lit") and together ("all").
"""
from __future__ import annotations

import json
import os

import numpy as np


def _psnr(a, b) -> float:
    if len(a) == 0:
        return float("nan")
    mse = float(np.mean((np.asarray(a, np.float64) - b) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def load(d: str) -> dict:
    import trimesh

    from graphkit import Camera
    from nodes.io.images import read_image

    def img(name):
        return read_image(os.path.join(d, name))[0]

    with open(os.path.join(d, "capture.json")) as f:
        meta = json.load(f)
    cams = {}
    for k in ("camera", "probe_camera"):
        with open(os.path.join(d, k + ".json")) as f:
            cams[k] = Camera.model_validate(json.load(f))
    refs = {ls["name"]: img(f"ref_{ls['name']}.exr") for ls in meta["spec"]["lights"]}
    return {"meta": meta, "photo": img("photo.exr"), "probe": img("probe.exr"), "skin": img("skin.exr")[..., 0] > 0.5,
            "mesh": trimesh.load(os.path.join(d, "mesh.ply"), process=False), "refs": refs, **cams}


def cast_shadows(mesh, points, normals, light, metres_per_unit) -> np.ndarray:
    """True where a ray from a surface point (world units) towards the light (world frame, a
    point light's position in metres) hits the mesh."""
    from . import make_capture as mc

    mi = mc._mi()
    scene = mi.load_dict({"type": "scene", "head": mc._mesh(mi, mesh, None, {"type": "diffuse"})})
    scale = float(np.median(np.ptp(np.asarray(mesh.vertices), axis=0)))
    eps = 2e-3 * scale
    out = np.zeros(len(points), bool)
    for i, (p, n) in enumerate(zip(points, normals)):
        o = p + n * eps
        if light.kind == "directional":
            d, tmax = np.asarray(light.direction, float), float("inf")
        else:
            v = np.asarray(light.position, float) / metres_per_unit - o
            tmax = float(np.linalg.norm(v))
            d = v / tmax
        ray = mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))
        ray.maxt = tmax
        out[i] = bool(scene.ray_test(ray))
    return out


def run(d: str, *, reflectance: dict | None = None, fit: dict | None = None, shininess: float | None = None,
        log=None, light_size: tuple[float, float] | None = None) -> dict:
    """The pipeline on capture folder ``d`` → {"rows": {light: {...}}, "probe": …, "material": …,
    "truth": …}.  ``light_size`` (radius_m of point relights, angular_radius_deg of directional
    ones): each row also holds the PSNRs of Render with the relight given that size (soft
    shadows), ``soft_psnr_lit`` / ``soft_psnr_all`` / ``soft_psnr_cast``, against the same
    reference, and on all skin against Mitsuba under the relight *with* that size
    (``make_capture_set.sized_reference``): hard Render ``area_hard_psnr_all``, soft Render
    ``area_soft_psnr_all``."""
    from scipy.ndimage import binary_erosion

    from graphkit import Image, Mask
    from graphkit.registry import default_registry
    from nodes.paris.data import make_capture_set as cs
    from nodes.paris.fit import FitSkinPhong
    from nodes.paris.probe import ProbeLight
    from nodes.paris.ratio import RatioImage
    from nodes.paris.reflectance import ReflectanceMap
    from nodes.paris.render import Render, ShadeFace, surface

    c = load(d)
    meta, cam, pcam, mesh = c["meta"], c["camera"], c["probe_camera"], c["mesh"]
    spec = cs.Spec(**{**meta["spec"], "lights": [cs.LightSpec(**ls) for ls in meta["spec"]["lights"]]})
    photo, probe = Image(c["photo"]), Image(c["probe"])
    pl = ProbeLight(ProbeLight.Params(**meta["probe"], flash_offset_m=tuple(meta["flash_offset_m"]),
                                      ball_position_m=tuple(meta["ball_position_m"]),
                                      face_position_m=tuple(meta["face_position_m"])))
    flash = pl.compute(probe=probe, camera=pcam)["light"]
    # ProbeLight's own measurement: without the flash offset, the direction at the face from the
    # ball's highlight and the parallax correction (ball and face positions), against the truth
    free = ProbeLight(ProbeLight.Params(**meta["probe"], ball_position_m=tuple(meta["ball_position_m"]),
                                        face_position_m=tuple(meta["face_position_m"])))
    est = free.compute(probe=probe, camera=pcam)["light"]
    true_dir = cs.to_world_m(spec, meta["flash_offset_m"]) - cs.to_world_m(spec, meta["face_position_m"])
    true_dir /= np.linalg.norm(true_dir)
    err_deg = float(np.degrees(np.arccos(np.clip(np.dot(true_dir, est.direction), -1, 1))))
    skin = Mask(binary_erosion(c["skin"], iterations=1).astype(np.float32))
    rnode = ReflectanceMap(ReflectanceMap.Params(**(reflectance or {})))
    rmap = rnode.compute(image=photo, mesh=mesh, camera=cam, skin=skin, light=flash)
    reg = default_registry()
    sh = reg.node_class("ShininessFromSaturation")().compute(reflectance=rmap["map"], light=flash, camera=cam,
                                                             image=photo, mesh=mesh, skin=skin)
    s_est = float(sh["shininess"] if isinstance(sh, dict) else sh)
    s = s_est if shininess is None else float(shininess)
    shaded = ShadeFace().compute(mesh=mesh, camera=cam, map=rmap["map"], light=flash)["image"]
    detail = RatioImage(RatioImage.Params(eps=0.01)).compute(a=photo, b=shaded)
    fr = FitSkinPhong(FitSkinPhong.Params(**{"starts": 2, **(fit or {})})).compute(
        image=photo, skin=skin, mesh=mesh, camera=cam, light=flash, shininess=s)
    mat, flash_fit = fr["material"], fr["light"]
    surf = surface(mesh, cam)
    sk = skin.alpha[surf.coverage] > 0.5
    rows = {}
    for ls in spec.lights:
        light = cs.relight_light(spec, ls)
        def relit(lt):
            return Render(Render.Params(shadow_map_size=512)).compute(
                mesh=mesh, camera=cam, material=mat, lights=[lt], detail=detail, texture_camera=cam,
                ambient=flash_fit)["image"].pixels[surf.coverage][sk]

        a = relit(light)
        b = c["refs"][ls.name][surf.coverage][sk]
        cast = cast_shadows(mesh, surf.points[sk], surf.normals[sk], light, cam.metres_per_unit)
        dcam = cs.light_direction_cam(ls.azimuth_deg, ls.elevation_deg)
        rows[ls.name] = {"angle": float(np.degrees(np.arccos(-dcam[2]))), "kind": ls.kind,
                         "distance_m": ls.distance_m, "psnr_lit": _psnr(a[~cast], b[~cast]),
                         "psnr_all": _psnr(a, b), "psnr_cast": _psnr(a[cast], b[cast]),
                         "cast_px": int(cast.sum()), "px": int(len(a))}
        if light_size is not None:
            from nodes.paris.render import LightSize

            size = {"radius_m": light_size[0]} if light.kind == "point" else {"angular_radius_deg": light_size[1]}
            s_ = relit(LightSize(LightSize.Params(**size)).compute(light))
            area = cs.sized_reference(d, spec, ls, tuple(light_size), log=log or (lambda m: None))
            area = area[surf.coverage][sk]
            rows[ls.name].update(soft_psnr_lit=_psnr(s_[~cast], b[~cast]), soft_psnr_all=_psnr(s_, b),
                                 soft_psnr_cast=_psnr(s_[cast], b[cast]), area_hard_psnr_all=_psnr(a, area),
                                 area_soft_psnr_all=_psnr(s_, area))
        if log:
            log(f"  {ls.name:>16} {rows[ls.name]['angle']:5.1f}° lit {rows[ls.name]['psnr_lit']:6.2f} "
                f"all {rows[ls.name]['psnr_all']:6.2f} dB")
    truth = meta
    return {"rows": rows, "material": mat.model_dump(), "flash": flash.model_dump(), "dir_err_deg": err_deg,
            "shininess": s_est, "truth": {"s": truth["phong_exponent"],
                                      "kd": [truth["kd_scale"] * a for a in truth["albedo_mean"]],
                                      "ambient": truth["ambient"]},
            "skin_px": int(sk.sum()), "cluster_deg": float(rmap["cluster_deg"])}
