"""Mirror-ball probe photos rendered with Mitsuba 3, for ProbeLight's automatic ball finding.

Each probe is a chrome ball (a slightly rough conductor) photographed by a pinhole camera (or
an orthographic one) in front of a backdrop, lit by a small spherical flash near the lens and
by an environment map: the CC0 HDRs of Debian's ``blender-data``
(``/usr/share/blender/datafiles/studiolights/world/*.exr``).  The backdrops are dark (black
cloth: albedo 0.02–0.08, some with a faint check pattern, one mid-grey), so the ball's rim,
which reflects what is behind the ball, is dark against a dark background: the silhouette is
faint while the environment's reflection inside the ball, and the ball's cast shadow on the
backdrop, make strong circular edges of the wrong size or place.  Some probes add the ball's
support stick.  The environment is scaled to a stated level (its 90th percentile) and its
brightest texels (the sun) are clipped, so that the flash is the only clipped source, as in the
paper's dark-room capture; the flash's reflection clips at 1 like a camera (``clip``) and a
camera's noise is added (shot + read, about 5 % at 0.05 of full scale; ``sensor_noise``
scales it).  Rendered with a stratified sampler (Monte Carlo noise about 1 %).

Probes are split into a TUNING set (what the ball finder was developed on) and a CHECK set
(held apart, used by tests/oracles/test_paris_probe_mitsuba.py); they differ in every
parameter (sizes, positions, backdrops, environments, flash offsets).  Three probes moved from
CHECK to TUNING after a check run refused them and the finder was changed for them (their
``note`` says so); the CHECK probes added after each such change are marked.

The truth of each probe (:func:`truth`): the ball's centre and radius in ProbeLight's
convention (pixel of the projected centre; radius r with arctan(r / (f·|ray|)) = the angular
radius of the ball, see ``nodes.paris.probe._rays_and_centre``; orthographic: the circle) and
the direction from the highlight point on the ball to the flash (the mirror reflects the
camera's ray there exactly into the flash), camera frame (OpenCV: x right, y down, z forward).

``python nodes/paris/data/make_probes.py OUT_DIR [names…]`` writes ``<name>.exr`` and
``<name>.json`` (spec + truth) for inspection; ``python nodes/paris/data/make_probes.py
--table [tuning|check|all]`` renders the probes and prints, per probe, the true and the found
ball and ProbeLight's direction error with the ball found and with the true ball given.
Units: metres, degrees, pixels.
"""
from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict, dataclass

import numpy as np

WORLD_DIR = "/usr/share/blender/datafiles/studiolights/world"


@dataclass(frozen=True)
class ProbeSpec:
    name: str
    env: str                          # blender-data world HDR (file stem)
    width: int = 320
    height: int = 240
    fov_deg: float | None = 14.0      # vertical field of view; None: orthographic
    ortho_height_m: float = 0.3       # orthographic view height (metres)
    ball_radius_m: float = 0.05
    distance_m: float = 1.2           # camera → ball centre
    frame_pos: tuple = (0.5, 0.5)     # where the ball centre is, as fractions of width, height
    backdrop_gap_m: float = 0.4       # ball centre → backdrop plane
    backdrop_albedo: tuple = (0.04, 0.04, 0.04)
    backdrop_size_m: float = 3.0      # square backdrop side (3 m fills the frame)
    checker: float = 0.0              # contrast of a check pattern on the backdrop (0: plain)
    texture: str = ""                 # a skimage.data picture printed on the backdrop (mean albedo: backdrop_albedo)
    room: bool = False                # the backdrop is the back wall of a box (floor, ceiling, side walls)
    lamps: tuple = ()                 # other lights: ((x, y, z) m camera frame, radius m, radiance), spheres
    other_weight: float = 1.0         # how often the environment and lamps are sampled against the flash (noise only)
    env_yaw_deg: float = 0.0
    env_level: float = 0.15           # the HDR is scaled so its 90th percentile radiance is this
    env_clip: float = 0.5             # …and clipped so its reflection stays below this (no sun)
    flash_offset_m: tuple = (0.0, -0.06, 0.0)   # from the pinhole (camera frame)
    flash_radius_m: float = 0.008
    flash_power: float = 1.0          # radiance scale of the flash
    roughness: float = 0.025          # Beckmann α of the ball
    reflectance: float = 0.8
    stick: bool = False               # a support stick below the ball
    ball: bool = True                 # False: the same scene without the ball (a "probe" with no ball)
    clip: bool = True                 # clip at 1 like a camera (False: an HDR probe)
    exposure: float = 1.0
    spp: int = 16                     # stratified: Monte Carlo noise ~1 %
    sensor_noise: float = 1.0         # scale of the camera noise added (shot + read, see render)
    seed: int = 0
    note: str = ""


TUNING = [
    ProbeSpec("t_centre_forest", "forest", spp=16),
    ProbeSpec("t_left_city", "city", frame_pos=(0.33, 0.55), distance_m=1.0, env_yaw_deg=70,
              flash_offset_m=(0.05, -0.04, 0.0)),
    ProbeSpec("t_small_studio", "studio", fov_deg=11.0, distance_m=1.8, frame_pos=(0.62, 0.4), env_level=0.18,
              backdrop_albedo=(0.06, 0.05, 0.05), stick=True),
    ProbeSpec("t_big_sunset", "sunset", width=400, height=300, distance_m=0.75, frame_pos=(0.52, 0.47),
              backdrop_gap_m=0.25, env_yaw_deg=200, checker=0.5),
    ProbeSpec("t_grey_courtyard", "courtyard", backdrop_albedo=(0.25, 0.25, 0.25), env_level=0.12,
              frame_pos=(0.45, 0.6), flash_offset_m=(-0.08, 0.0, 0.0)),
    ProbeSpec("t_wide_city", "city", fov_deg=28.0, distance_m=0.65, frame_pos=(0.45, 0.5),
              flash_offset_m=(-0.05, 0.02, 0.0), backdrop_albedo=(0.1, 0.1, 0.1), env_level=0.1,
              note="added after c_wide_studio's first check run: wide angle, close ball, the rim "
                   "reflects the lit backdrop (a ramp just inside the silhouette)"),
    ProbeSpec("t_wide_studio", "studio", fov_deg=30.0, distance_m=0.6, frame_pos=(0.6, 0.55),
              env_level=0.15, flash_offset_m=(0.06, 0.0, 0.0),
              note="a check probe (c_wide_studio) until its first check run refused it (rim ramp); "
                   "tuned on since"),
    ProbeSpec("t_large_forest", "forest", width=640, height=480, distance_m=0.55, frame_pos=(0.42, 0.55),
              env_yaw_deg=45, backdrop_gap_m=0.3, flash_offset_m=(0.02, -0.05, 0.0),
              note="the issue's scale: a ball of ~180 px radius"),
    ProbeSpec("t_noisy_night", "night", sensor_noise=3.0, frame_pos=(0.6, 0.6), env_level=0.2,
              flash_offset_m=(-0.04, -0.05, 0.0)),
    ProbeSpec("t_hdr_sunrise", "sunrise", clip=False, frame_pos=(0.4, 0.42), env_yaw_deg=260,
              backdrop_albedo=(0.05, 0.05, 0.06)),
    ProbeSpec("t_noisy_forest", "forest", sensor_noise=2.0, frame_pos=(0.4, 0.55), env_yaw_deg=200,
              flash_offset_m=(0.05, -0.03, 0.0),
              note="a check probe (c_noisy_forest) until its check run refused it; tuned on since"),
    ProbeSpec("t_far_backdrop_sunset", "sunset", backdrop_gap_m=1.5, distance_m=1.0, frame_pos=(0.52, 0.58),
              env_yaw_deg=330, flash_offset_m=(0.07, -0.02, 0.0),
              note="a check probe (c_far_backdrop_sunset) until its check run refused it (a silhouette barely above the noise); tuned on since"),
    ProbeSpec("t_ortho_interior", "interior", fov_deg=None, ortho_height_m=0.22, frame_pos=(0.55, 0.5), env_yaw_deg=90,
              env_level=0.05, backdrop_gap_m=0.3),
]

CHECK = [
    ProbeSpec("c_centre_sunrise", "sunrise", env_yaw_deg=35, flash_offset_m=(0.0, -0.05, 0.0)),
    ProbeSpec("c_topright_night", "night", frame_pos=(0.7, 0.3), env_level=0.25, distance_m=1.1,
              flash_offset_m=(0.04, -0.06, 0.0)),
    ProbeSpec("c_bottomleft_city", "city", frame_pos=(0.3, 0.68), env_yaw_deg=140, distance_m=1.3,
              backdrop_albedo=(0.03, 0.03, 0.035), stick=True),
    ProbeSpec("c_big_courtyard", "courtyard", width=384, height=288, distance_m=0.7, env_level=0.10,
              backdrop_gap_m=0.2, flash_offset_m=(-0.03, -0.07, 0.0)),
    ProbeSpec("c_tiny_forest", "forest", fov_deg=12.0, distance_m=2.0, frame_pos=(0.42, 0.45), env_yaw_deg=300,
              backdrop_albedo=(0.05, 0.045, 0.04), checker=0.6),
    ProbeSpec("c_grey_sunset", "sunset", backdrop_albedo=(0.3, 0.28, 0.26), frame_pos=(0.55, 0.42),
              env_yaw_deg=90, flash_offset_m=(0.0, -0.1, 0.0)),
    ProbeSpec("c_edge_interior", "interior", frame_pos=(0.2, 0.5), distance_m=1.0, env_level=0.07,
              env_yaw_deg=250, flash_power=2.0),
    ProbeSpec("c_ortho_sunrise", "sunrise", fov_deg=None, ortho_height_m=0.3, frame_pos=(0.4, 0.45),
              env_yaw_deg=180, checker=0.4),
    ProbeSpec("c_rough_city", "city", roughness=0.06, frame_pos=(0.5, 0.62), distance_m=0.9,
              env_yaw_deg=20, flash_power=2.0, stick=True),
    ProbeSpec("c_near_backdrop_night", "night", backdrop_gap_m=0.12, env_level=0.30, distance_m=1.0,
              frame_pos=(0.58, 0.5), flash_offset_m=(-0.05, -0.05, 0.0)),
    ProbeSpec("c_square_forest", "forest", width=256, height=256, fov_deg=18.0, distance_m=0.9,
              frame_pos=(0.5, 0.5), env_yaw_deg=120, backdrop_albedo=(0.02, 0.02, 0.02)),
    ProbeSpec("c_dim_courtyard", "courtyard", env_level=0.07, exposure=0.6, frame_pos=(0.36, 0.4),
              distance_m=1.4, flash_power=4.0, stick=True),
    # added after the first check run (never run before the finder's last change)
    ProbeSpec("c_large_city", "city", width=640, height=480, distance_m=0.65, frame_pos=(0.55, 0.45),
              env_yaw_deg=300, flash_offset_m=(-0.03, -0.06, 0.0)),
    ProbeSpec("c_hdr_interior", "interior", clip=False, frame_pos=(0.6, 0.45), env_yaw_deg=30,
              backdrop_albedo=(0.04, 0.035, 0.03), stick=True),
    ProbeSpec("c_checker_grey_night", "night", backdrop_albedo=(0.2, 0.2, 0.2), checker=0.5,
              frame_pos=(0.45, 0.5), env_level=0.3, flash_offset_m=(0.0, -0.08, 0.0)),
    # added after the second check run (never run before the finder's last change)
    ProbeSpec("c_noisy_sunrise", "sunrise", sensor_noise=2.5, frame_pos=(0.62, 0.38), env_yaw_deg=100,
              flash_offset_m=(-0.02, -0.07, 0.0)),
    ProbeSpec("c_far_backdrop_courtyard", "courtyard", backdrop_gap_m=1.2, distance_m=1.1,
              backdrop_albedo=(0.03, 0.03, 0.03), frame_pos=(0.47, 0.52), env_yaw_deg=210),
    ProbeSpec("c_ortho_forest_stick", "forest", fov_deg=None, ortho_height_m=0.26, frame_pos=(0.5, 0.45),
              stick=True, env_yaw_deg=15, flash_offset_m=(0.03, -0.05, 0.0)),
    ProbeSpec("c_big_night_checker", "night", width=384, height=288, distance_m=0.8, checker=0.7,
              backdrop_albedo=(0.06, 0.06, 0.06), env_level=0.3, frame_pos=(0.45, 0.5)),
    ProbeSpec("c_lower_studio", "studio", frame_pos=(0.5, 0.75), env_level=0.20, env_yaw_deg=60,
              backdrop_albedo=(0.08, 0.07, 0.06), flash_offset_m=(0.03, 0.06, 0.0)),
]

SPECS = {s.name: s for s in TUNING + CHECK}


def focal_px(spec: ProbeSpec) -> float:
    """Focal length in pixels (ProbeLight's convention: from the vertical field of view)."""
    return 0.5 * spec.height / np.tan(np.radians(spec.fov_deg) / 2)


def ball_centre(spec: ProbeSpec) -> np.ndarray:
    """Ball centre (metres, camera frame)."""
    u, v = spec.frame_pos[0] * spec.width, spec.frame_pos[1] * spec.height
    if spec.fov_deg is None:
        s = spec.ortho_height_m / spec.height
        return np.array([(u - spec.width / 2) * s, (v - spec.height / 2) * s, spec.distance_m])
    f = focal_px(spec)
    ray = np.array([(u - spec.width / 2) / f, (v - spec.height / 2) / f, 1.0])
    return ray / np.linalg.norm(ray) * spec.distance_m


def truth(spec: ProbeSpec) -> dict:
    """The ball in ProbeLight's pixel convention and the true flash direction (see the module)."""
    c = ball_centre(spec)
    R = spec.ball_radius_m
    w, h = spec.width, spec.height
    if spec.fov_deg is None:
        s = spec.ortho_height_m / h
        cx, cy, r = c[0] / s + w / 2, c[1] / s + h / 2, R / s
        cam = c - np.array([0.0, 0.0, c[2]])   # the orthographic "camera" direction: −z
    else:
        f = focal_px(spec)
        cx, cy = f * c[0] / c[2] + w / 2, f * c[1] / c[2] + h / 2
        dist = np.linalg.norm([(cx - w / 2) / f, (cy - h / 2) / f, 1.0])
        r = f * dist * np.tan(np.arcsin(R / np.linalg.norm(c)))
        cam = np.zeros(3)
    F = np.asarray(spec.flash_offset_m, float)
    # highlight point: the normal n bisects the directions to the camera and to the flash
    n = -c / np.linalg.norm(c)
    for _ in range(100):
        p = c + R * n
        to_cam = np.array([0.0, 0.0, -1.0]) if spec.fov_deg is None else (cam - p) / np.linalg.norm(cam - p)
        to_f = (F - p) / np.linalg.norm(F - p)
        n_new = (to_cam + to_f) / np.linalg.norm(to_cam + to_f)
        if np.linalg.norm(n_new - n) < 1e-12:
            break
        n = n_new
    p = c + R * n
    d = (F - p) / np.linalg.norm(F - p)
    return {"centre_x": float(cx), "centre_y": float(cy), "radius": float(r),
            "direction": [float(x) for x in d], "fov_deg": spec.fov_deg}


def _mi():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


def _env_bitmap(mi, spec: ProbeSpec):
    import OpenImageIO as oiio

    path = os.path.join(WORLD_DIR, f"{spec.env}.exr")
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: install Debian's blender-data (make sysdeps)")
    inp = oiio.ImageInput.open(path)
    px = np.asarray(inp.read_image(0, 0, 0, 3, "float"), np.float32)
    inp.close()
    px = px * (spec.env_level * spec.exposure / max(float(np.percentile(px, 90)), 1e-6))
    px = np.clip(px, 0, spec.env_clip / spec.reflectance)
    return mi.Bitmap(np.ascontiguousarray(px))


def scene_dict(spec: ProbeSpec) -> dict:
    mi = _mi()
    T = mi.ScalarTransform4f
    w, h = spec.width, spec.height
    if spec.fov_deg is None:
        sensor = {"type": "orthographic",
                  "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, -1, 0])
                  @ T().scale([spec.ortho_height_m / 2 * w / h] * 2 + [1])}   # Mitsuba: x half-width
    else:
        sensor = {"type": "perspective", "fov": spec.fov_deg, "fov_axis": "y",
                  "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, -1, 0])}
    sensor["film"] = {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                      "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "stratified", "sample_count": spec.spp, "seed": spec.seed}
    c = ball_centre(spec)
    zb = c[2] + spec.backdrop_gap_m
    half = spec.backdrop_size_m / 2
    if spec.checker > 0:
        a = np.asarray(spec.backdrop_albedo, float)
        refl = {"type": "checkerboard", "color0": {"type": "rgb", "value": (a * (1 + spec.checker)).tolist()},
                "color1": {"type": "rgb", "value": (a * (1 - spec.checker)).tolist()},
                "to_uv": T().scale([12, 12, 1])}
    elif spec.texture:
        refl = {"type": "bitmap", "bitmap": _texture_bitmap(mi, spec), "raw": True,
                "to_uv": T().scale([2, 2, 1])}
    else:
        refl = {"type": "rgb", "value": list(spec.backdrop_albedo)}
    # rectangle: [-1,1]² in xy facing +z; turned to face the camera (−z), centred behind the ball
    backdrop = {"type": "rectangle",
                "to_world": T().translate([c[0], c[1], zb]) @ T().rotate([0, 1, 0], 180) @ T().scale([half, half, 1]),
                "bsdf": {"type": "diffuse", "reflectance": refl}}
    F = list(spec.flash_offset_m)
    flash_rad = spec.flash_power * 5.0e4 * spec.exposure
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},   # camera → ball → backdrop → light
        "sensor": sensor,
        "ball": {"type": "sphere", "center": c.tolist(), "radius": spec.ball_radius_m,
                 "bsdf": {"type": "roughconductor", "material": "none", "distribution": "beckmann",
                          "alpha": spec.roughness,
                          "specular_reflectance": {"type": "rgb", "value": [spec.reflectance] * 3}}},
        "backdrop": backdrop,
        # the HDRs are +Y up; the camera frame is y down: turn the world over, then yaw it
        "env": {"type": "envmap", "bitmap": _env_bitmap(mi, spec),
                "to_world": T().rotate([0, 1, 0], spec.env_yaw_deg) @ T().rotate([1, 0, 0], 180)},
        "flash": {"type": "sphere", "center": F, "radius": spec.flash_radius_m,
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [flash_rad, 0.92 * flash_rad, 0.85 * flash_rad]}},
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}},
    }
    if not spec.ball:
        del scene["ball"]
    if spec.room:
        scene.update(_room(mi, spec, c, zb))
    for i, (pos, radius, radiance) in enumerate(spec.lamps):
        scene[f"lamp{i}"] = {"type": "sphere", "center": list(pos), "radius": radius,
                             "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [radiance * spec.exposure] * 3}}}
    if spec.other_weight != 1.0:   # the flash lights the backdrop: sampled more, less noise
        for e in [scene["env"]] + [scene[k]["emitter"] for k in scene if k.startswith("lamp")]:
            e["sampling_weight"] = spec.other_weight
    if spec.stick:
        # a grey support rod from the ball's bottom down out of the frame (camera frame: +y down)
        L = 1.0
        scene["stick"] = {"type": "cylinder", "radius": 0.006,
                          "p0": (c + [0, spec.ball_radius_m * 0.95, 0]).tolist(),
                          "p1": (c + [0, spec.ball_radius_m + L, 0]).tolist(),
                          "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.15, 0.15, 0.15]}}}
    return scene


def _texture_bitmap(mi, spec: ProbeSpec):
    """The skimage.data picture ``spec.texture`` as a linear albedo map of mean ``backdrop_albedo``."""
    import skimage.data

    img = getattr(skimage.data, spec.texture)().astype(np.float64) / 255.0
    img = img[..., :3] if img.ndim == 3 else np.repeat(img[..., None], 3, 2)
    img = img ** 2.2
    img = img / max(float(img.mean()), 1e-6) * np.asarray(spec.backdrop_albedo, float)
    return mi.Bitmap(np.ascontiguousarray(np.clip(img, 0, 0.95), np.float32))


def _room(mi, spec: ProbeSpec, c, zb) -> dict:
    """Floor, ceiling and side walls of a box whose back wall is the backdrop (camera frame: +y
    down); the floor 0.25 m below the ball, the box 1.6 m wide and 1.2 m high, open towards
    the camera, light grey walls and a darker floor."""
    T = mi.ScalarTransform4f
    y_floor, y_ceil, half_w = c[1] + 0.25, c[1] - 0.95, 0.8
    z0 = -0.3
    zc, zh = (zb + z0) / 2, (zb - z0) / 2

    def wall(centre, normal, up, sx, sy, albedo):
        return {"type": "rectangle",
                "to_world": T().look_at(origin=centre, target=[a + b for a, b in zip(centre, normal)], up=up)
                @ T().scale([sx, sy, 1]),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}}

    return {"floor": wall([c[0], y_floor, zc], [0, -1, 0], [0, 0, 1], half_w, zh, 0.12),
            "ceiling": wall([c[0], y_ceil, zc], [0, 1, 0], [0, 0, 1], half_w, zh, 0.5),
            "left": wall([c[0] - half_w, (y_floor + y_ceil) / 2, zc], [1, 0, 0], [0, 1, 0], zh, 0.6, 0.35),
            "right": wall([c[0] + half_w, (y_floor + y_ceil) / 2, zc], [-1, 0, 0], [0, 1, 0], zh, 0.6, 0.3)}


def render(spec: ProbeSpec, clip: bool | None = None) -> np.ndarray:
    """The probe photo: H×W×3 float32 linear RGB, clipped at 1 like a camera (``clip``, by
    default ``spec.clip``)."""
    clip = spec.clip if clip is None else clip
    mi = _mi()
    img = np.asarray(mi.render(mi.load_dict(scene_dict(spec)), seed=spec.seed), np.float64)[..., :3]
    # a camera's noise: shot noise (σ² ∝ signal) and read noise, about 5 % at 0.05 of full scale
    rng = np.random.default_rng(spec.seed + 1)
    sigma = spec.sensor_noise * (0.006 * np.sqrt(np.clip(img, 0, 1)) + 0.001)
    img = (img + sigma * rng.standard_normal(img.shape)).astype(np.float32)
    return np.clip(img, 0, 1) if clip else img


def table(specs) -> list[dict]:
    """Render each probe and run ProbeLight automatically and with the true ball given."""
    from graphkit import BadInput, Image
    from nodes.paris.ballfind import find_ball
    from nodes.paris.probe import ProbeLight

    def angle(a, b):
        return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1, 1))))

    rows = []
    for spec in specs:
        img = render(spec)
        t = truth(spec)
        fit = find_ball(img, spec.fov_deg)
        row = {"probe": spec.name, "true": (t["centre_x"], t["centre_y"], t["radius"]),
               "found": (fit.cx, fit.cy, fit.r) if fit.confident else None, "auto_deg": None,
               "given_deg": None, "refused": ""}
        try:
            lt = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg)).compute(probe=Image(img))["light"]
            row["auto_deg"] = angle(lt.direction, t["direction"])
        except BadInput as e:
            row["refused"] = e.message
        lt = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg, centre_x=t["centre_x"], centre_y=t["centre_y"],
                                          radius=t["radius"])).compute(probe=Image(img))["light"]
        row["given_deg"] = angle(lt.direction, t["direction"])
        rows.append(row)
        f = "refused" if row["found"] is None else "({:.2f}, {:.2f}, {:.2f})".format(*row["found"])
        a = "exit 2" if row["auto_deg"] is None else f"{row['auto_deg']:.2f}"
        print("| {} | ({:.2f}, {:.2f}, {:.2f}) | {} | {} | {:.2f} |".format(spec.name, *row["true"], f, a,
                                                                          row["given_deg"]), flush=True)
    return rows


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__)
        return 2
    if argv[0] == "--table":
        which = argv[1] if len(argv) > 1 else "check"
        specs = {"tuning": TUNING, "check": CHECK, "all": TUNING + CHECK}[which]
        print("| probe | true (cx, cy, r) px | found (cx, cy, r) px | direction error, found (°) | "
              "direction error, true ball given (°) |\n|---|---|---|---|---|")
        table(specs)
        return 0
    out = argv[0]
    names = argv[1:] or list(SPECS)
    os.makedirs(out, exist_ok=True)
    from nodes.io.images import encode_image

    for n in names:
        spec = SPECS[n]
        img = render(spec)
        with open(os.path.join(out, f"{n}.exr"), "wb") as f:
            f.write(encode_image(img, ".exr", 16))
        with open(os.path.join(out, f"{n}.json"), "w") as f:
            json.dump({"spec": asdict(spec), "truth": truth(spec)}, f, indent=1)
        print("wrote", n)
    return 0


if __name__ == "__main__":
    sys.exit(main())
