"""A varied set of Mitsuba 3 captures for Paris 2003 — the CHECK set.

**Rule: never tune on this set.**  The capture the code is tuned on is the sample capture
(``sample_capture/``, made by ``make_capture.py``: a 20,480-triangle head with a per-vertex
mottled albedo, a flash 6 cm above the lens at 2.5 m, the mirror ball *at* the face, a
perspective camera with the identity pose, directional relights).  Node defaults and any
constant in ``nodes/paris`` are chosen on that case (and on analytic / POV-Ray cases); the
captures here are only rendered and measured, to check the pipeline on data it has never
seen.  When a number here is bad, fix the model, not a default tuned to this set.

Every capture differs from the tuning case in several ways (see :data:`CAPTURES`):

* mesh: the head at other resolutions (1,280 … 81,920 triangles) and proportions, or the
  astronaut's FaceMesh (an open mask) — metres or millimetres;
* albedo: UV textures (equirectangular on the head, planar on the mask) — freckles, a tan with
  cheek blush, mottling, and one with *baked-in shading* (the texture darkened on one side and
  in the eye sockets, as a texture photographed under a light would be);
* camera: perspective at 0.8–2 m or orthographic, one with a non-identity pose (the world is
  not the camera frame);
* flash: a small sphere light (a point light for orthographic cameras, whose rays would hit
  a sphere at the lens) 3–10 cm from the lens on any side;
* probe: a mirror ball *beside* the face (10–22 cm away), photographed by its own wider camera
  (ProbeLight is given its centre/radius from the scene's truth: the automatic ball finding is
  another issue's work);
* ambient: a uniform environment of another colour and level;
* relights: point lights 0.7–2 m from the face and directional lights, within and beyond 45°.

Files per capture, in ``<out>/<name>/``: ``photo.exr``, ``probe.exr``, ``mesh.ply``,
``camera.json``, ``probe_camera.json``, ``skin.exr`` (the truth skin mask: 1 on skin-coloured
albedo), ``capture.json`` (the truth: positions in metres in the photo camera's frame, material,
lights, ProbeLight's ball parameters) and ``ref_<light>.exr`` (Mitsuba under each relight, the
same ambient, no flash).  Rendering is cached: a capture whose ``capture.json`` matches its
spec is not rendered again.

``python nodes/paris/data/make_capture_set.py [--out DIR] [--size N] [--spp N] [--only NAME]``
(default ``/tmp/relightkit-captures``, 160 px, 64 spp; run it with ``nice``).
``benchmarks/bench_paris_captures.py`` runs the pipeline on them and prints the table.
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import asdict, dataclass, field

import numpy as np

from . import make_capture as mc

DEFAULT_OUT = "/tmp/relightkit-captures"
BALL_RADIUS_M = 0.05
BALL_ALPHA = 0.02  # Beckmann roughness of the mirror ball
FLASH_RADIUS_M = 0.006
PEAK = 0.7  # a white diffuse surface facing the flash reads PEAK at the face


@dataclass
class LightSpec:
    """A relight: ``kind`` directional or point; angles (degrees) about the photo camera's axis
    (azimuth + = image right, elevation + = up); a point light sits ``distance_m`` from the
    face centre; ``intensity`` in flash units (× m² for point lights: relative to d²)."""

    name: str
    kind: str
    azimuth_deg: float
    elevation_deg: float
    distance_m: float = 0.0
    intensity: float = 1.0
    color: tuple = (1.0, 1.0, 1.0)


@dataclass
class Spec:
    name: str
    mesh: str = "head"  # "head" or "facemesh"
    subdivisions: int = 4
    radii_mm: tuple = (72.0, 98.0, 88.0)
    nose_mm: float = 22.0
    albedo: str = "freckles"  # freckles | tan | mottled | baked
    metres_per_unit: float = 0.001
    projection: str = "perspective"
    distance_m: float = 1.2  # lens → face centre
    field_m: float = 0.30  # the image width covers this much at the face
    probe_field_m: float = 0.60
    pose: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # world = camera frame moved: yaw, pitch, roll (deg), x, y, z (m)
    flash_offset_m: tuple = (0.0, -0.05, 0.0)
    ball_offset_m: tuple = (0.18, 0.0, 0.0)  # ball centre − face centre (camera frame)
    env: tuple = (0.02, 0.02, 0.02)
    spec_weight: float = 0.06
    alpha: float = 0.3
    seed: int = 1
    lights: list = field(default_factory=list)


def _std_lights(far_m=1.5, near_m=0.7):
    return [
        LightSpec("dir_front", "directional", 0.0, 0.0),
        LightSpec("dir_right30", "directional", 30.0, 10.0),
        LightSpec("dir_left40", "directional", -40.0, -5.0),
        LightSpec("pt_up25_%gm" % far_m, "point", 10.0, 25.0, far_m, far_m ** 2),
        LightSpec("pt_left35_%gm" % near_m, "point", -35.0, 10.0, near_m, near_m ** 2),
        LightSpec("pt_right20_2m", "point", 20.0, -10.0, 2.0, 4.0, (1.0, 0.85, 0.7)),
        LightSpec("dir_right60", "directional", 60.0, 0.0),
    ]


CAPTURES = [
    Spec("coarse_freckles", subdivisions=4, albedo="freckles", distance_m=1.2,
         flash_offset_m=(0.03, -0.04, 0.0), ball_offset_m=(0.20, 0.02, 0.0), env=(0.025, 0.022, 0.02),
         alpha=0.25, spec_weight=0.05, seed=2, lights=_std_lights(1.5, 0.7)),
    Spec("baked_ortho_metres", subdivisions=5, radii_mm=(76.0, 102.0, 92.0), nose_mm=26.0,
         albedo="baked", metres_per_unit=1.0, projection="orthographic", distance_m=1.6,
         flash_offset_m=(0.0, -0.08, 0.0), ball_offset_m=(-0.16, 0.10, 0.05), env=(0.015, 0.018, 0.024),
         alpha=0.3, spec_weight=0.07, seed=3, lights=_std_lights(1.2, 0.8)),
    Spec("fine_tan_posed", subdivisions=6, radii_mm=(70.0, 95.0, 86.0), nose_mm=19.0,
         albedo="tan", distance_m=2.0, field_m=0.32, probe_field_m=0.8,
         pose=(25.0, -10.0, 5.0, 0.4, -0.2, 1.5), flash_offset_m=(-0.10, 0.0, 0.0),
         ball_offset_m=(0.0, -0.22, 0.05), env=(0.02, 0.02, 0.02), alpha=0.35, spec_weight=0.06,
         seed=4, lights=_std_lights(2.0, 1.0)),
    Spec("facemesh_mottled", mesh="facemesh", albedo="mottled", distance_m=0.8, field_m=0.26,
         probe_field_m=0.55, flash_offset_m=(0.02, 0.05, 0.0), ball_offset_m=(0.15, 0.06, 0.02),
         env=(0.03, 0.025, 0.02), alpha=0.28, spec_weight=0.05, seed=5, lights=_std_lights(1.0, 0.7)),
    Spec("coarse_ortho_freckles", subdivisions=3, radii_mm=(74.0, 100.0, 90.0), nose_mm=20.0,
         albedo="freckles", projection="orthographic", distance_m=1.4, field_m=0.30,
         flash_offset_m=(0.04, 0.03, 0.0), ball_offset_m=(0.12, -0.12, 0.0), env=(0.02, 0.02, 0.025),
         alpha=0.22, spec_weight=0.05, seed=6, lights=_std_lights(1.4, 0.75)),
]


# ----------------------------------------------------------------------------------------------
# geometry


def _rot(yaw, pitch, roll):
    a, b, c = np.radians([yaw, pitch, roll])
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def camera_to_world(spec: Spec) -> np.ndarray:
    """4×4 camera → world (world units) of the photo camera."""
    M = np.eye(4)
    M[:3, :3] = _rot(*spec.pose[:3])
    M[:3, 3] = np.asarray(spec.pose[3:], np.float64) / spec.metres_per_unit
    return M


def face_centre_cam_m(spec: Spec) -> np.ndarray:
    return np.array([0.0, 0.0, spec.distance_m])


def _head_geometry(spec: Spec):
    """Head in mm in the camera frame (centre on the axis, its front at distance_m): (vertices,
    faces, unit-sphere directions, front weight)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=spec.subdivisions)
    u = np.asarray(m.vertices)
    p = _displace(u, spec)
    p[:, 2] += spec.distance_m * 1000.0 + spec.radii_mm[2]
    return p, np.asarray(m.faces), u


def _displace(u, spec: Spec):
    R = np.asarray(spec.radii_mm)
    p = u * R
    x, y = p[:, 0], p[:, 1]
    front = np.clip((-u[:, 2] - 0.1) / 0.4, 0, 1)
    g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
    disp = (spec.nose_mm * g(0, 8, 9, 20) - 7 * (g(-30, -18, 11, 9) + g(30, -18, 11, 9))
            + 4 * (g(-30, -36, 16, 5) + g(30, -36, 16, 5)) + 5 * g(0, 48, 17, 6) + 6 * g(0, 78, 16, 10))
    return p + u * (disp * front)[:, None]


def _features(x, y, front):
    """(brow, lips, eye-white, iris) weights at head coordinates (mm) on the front."""
    g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
    brow = np.clip(g(-30, -36, 15, 4) + g(30, -36, 15, 4), 0, 1) * front
    lips = np.clip(g(0, 48, 16, 5) * 1.5, 0, 1) * front
    eyew = np.clip((g(-30, -18, 9, 5) + g(30, -18, 9, 5)) * 1.6, 0, 1) * front
    iris = np.clip((g(-30, -18, 3.5, 3.5) + g(30, -18, 3.5, 3.5)) * 1.5, 0, 1) * front
    return brow, lips, eyew, iris


def _skin_pattern(kind: str, x, y, front, rng, sx=1.0):
    """Skin albedo (N×3) of the pattern ``kind`` at head coordinates x, y (mm)."""
    if kind == "freckles":
        base = np.array([0.66, 0.46, 0.37])
        spots = np.zeros_like(x)
        cx, cy = rng.uniform(-60, 60, 140) * sx, rng.uniform(-40, 45, 140)
        rad = rng.uniform(1.5, 3.5, 140)
        for a, b, r in zip(cx, cy, rad):
            spots += np.exp(-((x - a) ** 2 + (y - b) ** 2) / (r * r))
        alb = base[None] * (1 - 0.35 * np.clip(spots, 0, 1)[:, None] * np.array([0.8, 1.0, 1.15]))
        alb *= (1 + 0.05 * np.sin(0.21 * x + 0.4) * np.sin(0.17 * y))[:, None]
    elif kind == "tan":
        base = np.array([0.55, 0.37, 0.27])
        t = np.clip((y + 20) / 80, 0, 1)  # the lower face more tanned
        alb = base[None] * (1 + 0.18 * (1 - t))[:, None] * np.array([1.0, 0.97, 0.95])
        blush = np.exp(-(((np.abs(x) - 38) / 14) ** 2 + ((y - 12) / 12) ** 2))
        alb = alb * (1 - 0.25 * blush[:, None] * np.array([0.0, 1.0, 0.8]))
        alb *= (1 + 0.07 * np.sin(0.5 * x + 0.3 * y) * np.sin(0.33 * y - 0.2 * x))[:, None]
    else:  # mottled (also the base of "baked")
        base = np.array([0.62, 0.42, 0.33])
        mott = (1 + 0.12 * np.sin(0.27 * x + 2.0) * np.sin(0.33 * y + 1.0)
                + 0.07 * np.sin(0.8 * x + 0.6 * y) + 0.04 * np.sin(1.7 * x - 1.3 * y))
        alb = base[None] * mott[:, None]
    return alb


def _albedo_at(spec: Spec, pts, udir, rng):
    """(albedo N×3, skin weight N) at head points (mm, head-centred) / unit directions."""
    x, y = pts[:, 0], pts[:, 1]
    front = np.clip((-udir[:, 2] - 0.1) / 0.4, 0, 1)
    kind = "mottled" if spec.albedo == "baked" else spec.albedo
    alb = _skin_pattern(kind, x, y, front, rng)
    if spec.albedo == "baked":
        # shading baked into the texture: darker on the subject's left and below, and in the
        # eye sockets, as a texture photographed under a light from the upper right would be
        lb = np.array([-0.7, -0.3, -0.65])
        lb /= np.linalg.norm(lb)
        sh = 0.5 + 0.5 * np.clip(udir @ lb, 0, 1)
        g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
        sh *= 1 - 0.25 * np.clip(g(-30, -18, 14, 11) + g(30, -18, 14, 11), 0, 1) * front
        alb = alb * sh[:, None]
    brow, lips, eyew, iris = _features(x, y, front)
    alb = alb * (1 - brow[:, None]) + np.array([0.10, 0.07, 0.05]) * brow[:, None]
    alb = alb * (1 - lips[:, None]) + np.array([0.50, 0.18, 0.18]) * lips[:, None]
    alb = alb * (1 - eyew[:, None]) + np.array([0.75, 0.72, 0.70]) * eyew[:, None]
    alb = alb * (1 - iris[:, None]) + np.array([0.15, 0.10, 0.06]) * iris[:, None]
    skin_w = np.clip(1 - 2 * np.maximum.reduce([brow, lips, eyew]), 0, 1)
    return np.clip(alb, 0.01, 0.95), skin_w


def _head_texture(spec: Spec, res=(384, 768)):
    """Equirectangular albedo and skin-weight textures of the head: texel (row v·H, col u·W)
    with u = atan2(x, −z)/2π + ½ (the face at u = ½), v = acos(y)/π on the unit sphere."""
    rng = np.random.default_rng(spec.seed)
    H, W = res
    v = (np.arange(H) + 0.5) / H
    u = (np.arange(W) + 0.5) / W
    th, ph = np.meshgrid(v * np.pi, (u - 0.5) * 2 * np.pi, indexing="ij")
    udir = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1).reshape(-1, 3)
    pts = _displace(udir, spec)
    alb, sk = _albedo_at(spec, pts, udir, rng)
    return alb.reshape(H, W, 3).astype(np.float32), sk.reshape(H, W).astype(np.float32)


def _head_uv(udir):
    u = np.arctan2(udir[:, 0], -udir[:, 2]) / (2 * np.pi) + 0.5
    v = np.arccos(np.clip(udir[:, 1], -1, 1)) / np.pi
    return np.stack([u, v], 1)


def build(spec: Spec):
    """(mesh in world units, uv N×2, albedo texture H×W×3, skin texture H×W, face centre in the
    camera frame (m))."""
    import trimesh

    if spec.mesh == "head":
        V, F, udir = _head_geometry(spec)
        uv = _head_uv(udir)
        tex, sk = _head_texture(spec)
    else:
        V, F, uv, tex, sk = _facemesh_geometry(spec)
    Vm = V * 0.001  # metres, camera frame
    Vw = (Vm / spec.metres_per_unit) @ camera_to_world(spec)[:3, :3].T + camera_to_world(spec)[:3, 3]
    mesh = trimesh.Trimesh(Vw, F, process=False)
    # the face's centre: the front of the head on the optical axis
    return mesh, uv, tex, sk


def _facemesh_geometry(spec: Spec):
    m, _, _ = mc.facemesh_head(subdivisions=2)
    V = np.asarray(m.vertices, np.float64)
    V = V - [0, 0, mc.DISTANCE_MM - 88.0] + [0, 0, spec.distance_m * 1000.0]  # its front at distance_m
    F = np.asarray(m.faces)
    lo, hi = V.min(0), V.max(0)
    uv = np.stack([(V[:, 0] - lo[0]) / (hi[0] - lo[0]), (V[:, 1] - lo[1]) / (hi[1] - lo[1])], 1)
    rng = np.random.default_rng(spec.seed)
    H, W = 384, 384
    yy, xx = np.mgrid[0:H, 0:W]
    x = lo[0] + (xx.ravel() + 0.5) / W * (hi[0] - lo[0])
    y = lo[1] + (yy.ravel() + 0.5) / H * (hi[1] - lo[1])
    alb = _skin_pattern(spec.albedo, x, y, np.ones_like(x), rng)
    tex = np.clip(alb, 0.01, 0.95).reshape(H, W, 3).astype(np.float32)
    return V, F, uv, tex, np.ones((H, W), np.float32)


# ----------------------------------------------------------------------------------------------
# cameras and rendering


def cameras(spec: Spec, size: int, probe_size: int):
    """(photo camera, probe camera) as graphkit Cameras (world_to_camera from the pose)."""
    from graphkit import Camera

    w2c = np.linalg.inv(camera_to_world(spec)).tolist()
    out = []
    for n, field_m in ((size, spec.field_m), (probe_size, spec.probe_field_m)):
        if spec.projection == "orthographic":
            out.append(Camera(width=n, height=n, projection="orthographic", pixels_per_m=n / field_m,
                              cx=n / 2, cy=n / 2, world_to_camera=w2c, metres_per_unit=spec.metres_per_unit))
        else:
            f = n * spec.distance_m / field_m
            out.append(Camera(width=n, height=n, fx=f, fy=f, cx=n / 2, cy=n / 2, world_to_camera=w2c,
                              metres_per_unit=spec.metres_per_unit))
    return out


def _sensor(mi, cam, spp, seed):
    """A Mitsuba sensor equal to the graphkit camera (square images, centred principal point)."""
    R, C = cam.rotation, cam.position
    T = mi.ScalarTransform4f.look_at(origin=list(C), target=list(C + R[2]), up=list(-R[1]))
    film = {"type": "hdrfilm", "width": cam.width, "height": cam.height,
            "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    # stratified: at 64 spp two renders differ by ~57 dB on skin (independent sampling: 28 dB,
    # which would swamp the measurement)
    sampler = {"type": "stratified", "sample_count": spp, "seed": seed}
    if cam.orthographic:
        half = cam.width / 2 / cam.scale
        return {"type": "orthographic", "to_world": T @ mi.ScalarTransform4f.scale([half, half, 1.0]),
                "film": film, "sampler": sampler}
    fov = float(np.degrees(2 * np.arctan(cam.width / (2 * cam.fx))))
    return {"type": "perspective", "fov": fov, "fov_axis": "x", "to_world": T, "film": film,
            "sampler": sampler, "near_clip": 1e-3 / cam.metres_per_unit}


def _mi_mesh(mi, mesh, uv, bsdf):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    m = mi.Mesh("head", len(mesh.vertices), len(mesh.faces), props=props, has_vertex_normals=True,
                has_vertex_texcoords=uv is not None)
    prm = mi.traverse(m)
    T = type(prm["vertex_positions"])
    prm["vertex_positions"] = T(np.asarray(mesh.vertices, np.float32).ravel())
    prm["vertex_normals"] = T(np.asarray(mesh.vertex_normals, np.float32).ravel())
    if uv is not None:
        prm["vertex_texcoords"] = T(np.asarray(uv, np.float32).ravel())
    prm["faces"] = type(prm["faces"])(np.asarray(mesh.faces, np.uint32).ravel())
    prm.update()
    return m


def to_world_m(spec: Spec, p_cam_m) -> np.ndarray:
    """A camera-frame point (m) → world units."""
    M = camera_to_world(spec)
    return M[:3, :3] @ (np.asarray(p_cam_m, np.float64) / spec.metres_per_unit) + M[:3, 3]


def flash_irradiance_mi(spec: Spec) -> float:
    """Mitsuba irradiance (scene units) the flash gives the face centre: PEAK·π."""
    return PEAK * np.pi


def light_direction_cam(az, el):
    a, e = np.radians(az), np.radians(el)
    return np.array([np.sin(a) * np.cos(e), -np.sin(e), -np.cos(a) * np.cos(e)])


def render(spec: Spec, cam, mesh, uv, tex, what: str, light: LightSpec | None = None, spp: int = 64,
           seed: int = 0, light_size: tuple[float, float] = (0.0, 0.0)):
    """Render 'photo' (flash + ambient), 'probe' (ball + flash + ambient) or 'relight' (the
    light + ambient) in Mitsuba; H×W×3 float32.  ``light_size``: the relight as an area light,
    (radius in m of a point light's sphere, angular radius in degrees of a directional light's
    disc: a sphere 100 m away), with the same irradiance at normal incidence."""
    import mitsuba as mi

    mc._mi()
    u = spec.metres_per_unit
    E = flash_irradiance_mi(spec)
    C = face_centre_cam_m(spec)
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
             "sensor": _sensor(mi, cam, spp, 97 * spec.seed + seed),
             "env": {"type": "constant", "radiance": {"type": "rgb", "value": list(spec.env)}}}
    if what == "probe":
        B = C + np.asarray(spec.ball_offset_m)
        scene["ball"] = {"type": "sphere", "center": list(to_world_m(spec, B)), "radius": BALL_RADIUS_M / u,
                         "bsdf": {"type": "roughconductor", "material": "none", "alpha": BALL_ALPHA,
                                  "distribution": "beckmann"}}
    else:
        bsdf = {"type": "blendbsdf", "weight": spec.spec_weight,
                "bsdf_0": {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(tex),
                                                              "filter_type": "bilinear", "raw": True}},
                "bsdf_1": {"type": "roughconductor", "material": "none", "distribution": "beckmann",
                           "alpha": spec.alpha}}
        scene["head"] = _mi_mesh(mi, mesh, uv, bsdf)
    if what in ("photo", "probe"):
        Fp = np.asarray(spec.flash_offset_m)
        d_m = np.linalg.norm(C - Fp)
        I = E * (d_m / u) ** 2  # radiant intensity, scene units
        if spec.projection == "orthographic":
            # an orthographic camera's rays pass the lens's plane everywhere: a point emitter,
            # which nothing sees
            scene["flash"] = {"type": "point", "position": list(to_world_m(spec, Fp)),
                              "intensity": {"type": "rgb", "value": float(I)}}
        else:  # a small sphere light beside the pinhole
            r = FLASH_RADIUS_M / u
            scene["flash"] = {"type": "sphere", "center": list(to_world_m(spec, Fp)), "radius": r,
                              "emitter": {"type": "area", "radiance": {"type": "rgb", "value": float(I / (np.pi * r * r))}},
                              "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}}
    if light is not None:
        Rw = camera_to_world(spec)[:3, :3]
        d_cam = light_direction_cam(light.azimuth_deg, light.elevation_deg)
        rgb = np.asarray(light.color, np.float64) * light.intensity
        radius_m, angle = light_size[0], np.radians(light_size[1])
        if light.kind == "directional" and angle > 0:
            far = 100.0
            scene["sun"] = _sphere_light(to_world_m(spec, C + far * d_cam), far * np.sin(angle) / u,
                                         rgb * E / (np.pi * np.sin(angle) ** 2))
        elif light.kind == "directional":
            scene["sun"] = {"type": "directional", "direction": list(-(Rw @ d_cam)),
                            "irradiance": {"type": "rgb", "value": list(rgb * E)}}
        elif radius_m > 0:
            r = radius_m / u
            scene["lamp"] = _sphere_light(to_world_m(spec, C + light.distance_m * d_cam), r,
                                          rgb * E / u ** 2 / (np.pi * r * r))
        else:
            P = C + light.distance_m * d_cam
            scene["lamp"] = {"type": "point", "position": list(to_world_m(spec, P)),
                             "intensity": {"type": "rgb", "value": list(rgb * E / u ** 2)}}
    img = mi.render(mi.load_dict(scene), spp=spp)
    return np.asarray(img, np.float32)[..., :3]


def relight_light(spec: Spec, light: LightSpec):
    """The graphkit Light (world frame, metres, flash units) equal to the Mitsuba relight."""
    from graphkit import Light

    Rw = camera_to_world(spec)[:3, :3]
    d_cam = light_direction_cam(light.azimuth_deg, light.elevation_deg)
    if light.kind == "directional":
        return Light(direction=tuple(Rw @ d_cam), color=tuple(light.color), intensity=light.intensity)
    P = face_centre_cam_m(spec) + light.distance_m * d_cam
    Pw = to_world_m(spec, P) * spec.metres_per_unit
    return Light(kind="point", position=tuple(Pw), direction=tuple(Rw @ d_cam), color=tuple(light.color),
                 intensity=light.intensity)


def probe_ball_params(spec: Spec, pcam) -> dict:
    """ProbeLight's centre_x, centre_y, radius (pixels) for the ball, from the scene's truth, in
    ProbeLight's own camera model (perspective: the ray through the centre pixel hits the ball's
    centre and the silhouette's angular radius α has sin α = R/|B|)."""
    B = face_centre_cam_m(spec) + np.asarray(spec.ball_offset_m)
    Bw = to_world_m(spec, B)
    uv, _ = pcam.project(Bw[None])
    cx, cy = (float(x) for x in uv[0])
    if pcam.orthographic:
        r = BALL_RADIUS_M * pcam.pixels_per_m
    else:
        f = pcam.fy
        dist = np.linalg.norm([(cx - pcam.width / 2) / f, (cy - pcam.height / 2) / f, 1.0])
        r = f * dist * np.tan(np.arcsin(BALL_RADIUS_M / np.linalg.norm(B)))
    return {"centre_x": cx, "centre_y": cy, "radius": float(r)}


def truth(spec: Spec, pcam) -> dict:
    C = face_centre_cam_m(spec)
    return {
        "spec": asdict(spec),
        "face_position_m": list(C),
        "ball_position_m": list(C + np.asarray(spec.ball_offset_m)),
        "flash_offset_m": list(spec.flash_offset_m),
        "probe": probe_ball_params(spec, pcam),
        "phong_exponent": mc.phong_exponent_of_beckmann(spec.alpha),
        "kd_scale": PEAK * (1 - spec.spec_weight),  # true kd = kd_scale × albedo (flash units)
        "ambient": [float(a) * np.pi / flash_irradiance_mi(spec) for a in spec.env],
    }


def skin_albedo_mean(spec: Spec, mesh, uv, tex, sk, cam) -> list:
    """Mean true albedo over the visible skin (for the fitted colour's truth)."""
    mask, alb = truth_maps(mesh, uv, tex, sk, cam)
    return [float(v) for v in alb[mask].mean(0)]


def truth_maps(mesh, uv, tex, sk, cam):
    """(skin mask H×W bool, albedo H×W×3) per pixel of ``cam`` from the textures."""
    from nodes.common import raster

    r = raster.rasterize(mesh.vertices, mesh.faces, cam)
    UV = raster.interpolate(r, mesh.faces, uv)
    H, W = tex.shape[:2]
    ix = np.clip((UV[..., 0] * W).astype(np.int64), 0, W - 1)
    iy = np.clip((UV[..., 1] * H).astype(np.int64), 0, H - 1)
    skin = r.coverage & (sk[iy, ix] > 0.5)
    return skin, tex[iy, ix]


def _sphere_light(centre, radius: float, radiance) -> dict:
    """A black sphere emitting ``radiance`` (RGB) uniformly (scene units)."""
    return {"type": "sphere", "center": [float(x) for x in centre], "radius": float(radius),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [float(x) for x in radiance]}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}}


def sized_reference(d: str, spec: Spec, light: LightSpec, light_size: tuple[float, float], log=print):
    """Mitsuba's render of capture ``d`` under ``light`` as an area light of ``light_size``
    (see :func:`render`), cached beside the capture as ``ref_<light>_r<m>_a<deg>.exr``."""
    from nodes.io.images import encode_image, read_image

    path = os.path.join(d, f"ref_{light.name}_r{light_size[0]:g}_a{light_size[1]:g}.exr")
    if not os.path.exists(path):
        with open(os.path.join(d, "capture.json")) as f:
            key = json.load(f)["key"]
        log(f"{spec.name}: {os.path.basename(path)}")
        mesh, uv, tex, _ = build(spec)
        cam, _ = cameras(spec, key["size"], key["probe_size"])
        seed = 2 + [x.name for x in spec.lights].index(light.name)
        img = render(spec, cam, mesh, uv, tex, "relight", light, spp=key["spp"], seed=seed, light_size=light_size)
        with open(path + ".part", "wb") as f:
            f.write(encode_image(np.asarray(img, np.float32), ".exr", 32))
        os.replace(path + ".part", path)
    return read_image(path)[0]


def make(spec: Spec, out: str, size: int = 160, probe_size: int = 384, spp: int = 64, log=print) -> str:
    """Render one capture into ``out/<name>`` (skipped when already there for this spec)."""
    from nodes.io.images import encode_image

    d = os.path.join(out, spec.name)
    key = json.loads(json.dumps({"spec": asdict(spec), "size": size, "probe_size": probe_size, "spp": spp,
                                 "version": 3}))
    meta_path = os.path.join(d, "capture.json")
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            if json.load(f).get("key") == key:
                return d
    os.makedirs(d, exist_ok=True)
    mesh, uv, tex, sk = build(spec)
    cam, pcam = cameras(spec, size, probe_size)

    def save(name, img):
        with open(os.path.join(d, name), "wb") as f:
            f.write(encode_image(np.asarray(img, np.float32), ".exr", 32))

    log(f"{spec.name}: photo")
    save("photo.exr", render(spec, cam, mesh, uv, tex, "photo", spp=spp, seed=0))
    log(f"{spec.name}: probe")
    save("probe.exr", render(spec, pcam, mesh, uv, tex, "probe", spp=spp, seed=1))
    for i, light in enumerate(spec.lights):
        log(f"{spec.name}: {light.name}")
        save(f"ref_{light.name}.exr", render(spec, cam, mesh, uv, tex, "relight", light, spp=spp, seed=2 + i))
    skin, _ = truth_maps(mesh, uv, tex, sk, cam)
    save("skin.exr", skin.astype(np.float32)[..., None])
    mesh.export(os.path.join(d, "mesh.ply"))
    for name, c in (("camera.json", cam), ("probe_camera.json", pcam)):
        with open(os.path.join(d, name), "w") as f:
            json.dump(c.model_dump(exclude_none=True), f, indent=1)
    meta = truth(spec, pcam)
    meta["albedo_mean"] = skin_albedo_mean(spec, mesh, uv, tex, sk, cam)
    meta["key"] = key
    with open(meta_path, "w") as f:
        json.dump(meta, f, indent=1)
    return d


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=DEFAULT_OUT)
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--probe-size", type=int, default=384)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--only", action="append", help="capture name (repeatable)")
    a = ap.parse_args(argv)
    for spec in CAPTURES:
        if a.only and spec.name not in a.only:
            continue
        print("wrote", make(spec, a.out, a.size, a.probe_size, a.spp))


if __name__ == "__main__":
    main()
