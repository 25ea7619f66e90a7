"""A synthetic Paris-2003 capture rendered with Mitsuba 3 (the §1 input set).

A head-like mesh (ellipsoid with nose, brows, eye sockets, lips and chin; mm, OpenCV camera
frame: x right, y down, z forward) with a known per-vertex albedo and a known diffuse + glossy
material (Mitsuba ``blendbsdf`` of a ``diffuse`` and a Beckmann ``roughconductor``), lit by a
small spherical light 60 mm above the camera (the flash) plus a faint uniform environment, and
a rough mirror ball under the same light (the probe).  The same module renders references
under directional lights for the oracle test (tests/oracles/test_paris_face_mitsuba.py).

``python nodes/paris/data/make_capture.py`` writes ``sample_capture/`` beside this file:
photo.exr, probe.exr, mesh.ply, camera.json (read by graphs/face_capture.yaml).
"""
from __future__ import annotations

import json
import os

import numpy as np

DISTANCE_MM = 2500.0  # camera → head centre
FLASH_POS = (0.0, -60.0, 0.0)  # 6 cm above the optical centre (Paris 2003 §6)
FLASH_RADIUS = 8.0  # mm
SPEC_WEIGHT = 0.06  # blendbsdf weight of the glossy lobe
ALPHA = 0.3  # Beckmann roughness of the glossy lobe
ENV_RADIANCE = 0.02  # uniform environment (ambient)


def phong_exponent_of_beckmann(alpha: float = ALPHA) -> float:
    """Phong (r·v)^s exponent of a Beckmann lobe: Blinn (n·h)^s' with s' = 2/α² − 2 (Walter et
    al. 2007), and (r·v) = cos 2θ_h near the peak, so s ≈ s'/4."""
    return (2.0 / alpha ** 2 - 2.0) / 4.0


def head_mesh(subdivisions: int = 5):
    """(trimesh head in mm at DISTANCE_MM, per-vertex albedo N×3, per-vertex skin weight N)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    u = np.asarray(m.vertices)  # unit sphere
    R = np.array([72.0, 98.0, 88.0])
    p = u * R
    x, y = p[:, 0], p[:, 1]
    front = np.clip((-u[:, 2] - 0.1) / 0.4, 0, 1)  # faces the camera (-z)
    g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
    disp = (22 * g(0, 8, 9, 20) - 7 * (g(-30, -18, 11, 9) + g(30, -18, 11, 9))
            + 4 * (g(-30, -36, 16, 5) + g(30, -36, 16, 5)) + 5 * g(0, 48, 17, 6) + 6 * g(0, 78, 16, 10))
    p = p + u * (disp * front)[:, None]
    p[:, 2] += DISTANCE_MM
    m = trimesh.Trimesh(p, np.asarray(m.faces), process=False)
    # albedo: skin with a mottled pattern, dark brows, red lips, light eyes with a dark iris
    skin = np.array([0.60, 0.40, 0.31])
    mott = 1 + 0.10 * np.sin(0.31 * x + 1.0) * np.sin(0.27 * y) + 0.06 * np.sin(0.9 * x - 0.7 * y)
    alb = skin[None, :] * mott[:, None]
    brow = np.clip(g(-30, -36, 15, 4) + g(30, -36, 15, 4), 0, 1) * front
    lips = np.clip(g(0, 48, 16, 5) * 1.5, 0, 1) * front
    eyew = np.clip((g(-30, -18, 9, 5) + g(30, -18, 9, 5)) * 1.6, 0, 1) * front
    iris = np.clip((g(-30, -18, 3.5, 3.5) + g(30, -18, 3.5, 3.5)) * 1.5, 0, 1) * front
    alb = alb * (1 - brow[:, None]) + np.array([0.10, 0.07, 0.05]) * brow[:, None]
    alb = alb * (1 - lips[:, None]) + np.array([0.50, 0.18, 0.18]) * lips[:, None]
    alb = alb * (1 - eyew[:, None]) + np.array([0.75, 0.72, 0.70]) * eyew[:, None]
    alb = alb * (1 - iris[:, None]) + np.array([0.15, 0.10, 0.06]) * iris[:, None]
    skin_w = np.clip(1 - 2 * np.maximum.reduce([brow, lips, eyew]), 0, 1)
    return m, np.clip(alb, 0, 1), skin_w


def facemesh_head(subdivisions: int = 2):
    """(mesh, albedo, skin weight) from the astronaut's FaceMesh mesh (mm): subdivided
    ``subdivisions`` times (finer albedo and shading), moved so its centre is on the optical
    axis at DISTANCE_MM, with the mottled skin albedo of :func:`head_mesh`.  The mesh is an
    open mask (holes at the eyes and mouth).  Needs the graphkit-mediapipe plugin."""
    import skimage.data
    import trimesh

    from graphkit import Image
    from graphkit.registry import default_registry
    from nodes.common.color import srgb_to_linear

    photo = Image(srgb_to_linear(skimage.data.astronaut() / 255.0))
    fm = default_registry().node_class("FaceMesh")().compute(image=photo)["mesh"]
    V, F = np.asarray(fm.vertices, np.float64), np.asarray(fm.faces, np.int64)
    for _ in range(subdivisions):
        V, F = trimesh.remesh.subdivide(V, F)
    lo, hi = V.min(0), V.max(0)
    V = V - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]] + [0, 0, DISTANCE_MM - 88.0]
    m = trimesh.Trimesh(V, F, process=False)
    x, y = V[:, 0], V[:, 1]
    skin = np.array([0.60, 0.40, 0.31])
    mott = 1 + 0.10 * np.sin(0.31 * x + 1.0) * np.sin(0.27 * y) + 0.06 * np.sin(0.9 * x - 0.7 * y)
    alb = np.clip(skin[None, :] * mott[:, None], 0, 1)
    return m, alb, np.ones(len(V))


def camera(size: int = 128):
    from graphkit import Camera

    f = size * DISTANCE_MM / 270.0
    return Camera(width=size, height=size, fx=f, fy=f, cx=size / 2, cy=size / 2, metres_per_unit=0.001)


def flash_intensity(peak: float = 0.7) -> float:
    """Radiant intensity of the flash (W/sr-ish) so a frontal white diffuse point reads ~peak."""
    d = DISTANCE_MM - 88.0
    return peak * np.pi * d * d


def flash_light_direction() -> np.ndarray:
    c = np.array([0.0, 0.0, DISTANCE_MM - 88.0])
    v = np.asarray(FLASH_POS) - c
    return v / np.linalg.norm(v)


def _mi():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


def _mesh(mi, m, albedo, bsdf):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh("head", len(m.vertices), len(m.faces), props=props, has_vertex_normals=True)
    prm = mi.traverse(mesh)
    T = type(prm["vertex_positions"])
    prm["vertex_positions"] = T(np.asarray(m.vertices, np.float32).ravel())
    prm["vertex_normals"] = T(np.asarray(m.vertex_normals, np.float32).ravel())
    prm["faces"] = type(prm["faces"])(np.asarray(m.faces, np.uint32).ravel())
    if albedo is not None:
        mesh.add_attribute("vertex_color", 3, T(np.asarray(albedo, np.float32).ravel()))
    prm.update()
    return mesh


def _sensor(mi, cam, spp, seed=7):
    fov = float(np.degrees(2 * np.arctan(cam.width / (2 * cam.fx))))
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f.look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, -1, 0]),
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            # stratified: far less noise than independent sampling at the same spp
            "sampler": {"type": "stratified", "sample_count": spp, "seed": seed}}


def skin_bsdf():
    return {"type": "blendbsdf", "weight": SPEC_WEIGHT,
            "bsdf_0": {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}},
            "bsdf_1": {"type": "roughconductor", "material": "none", "distribution": "beckmann",
                       "alpha": ALPHA}}


def _flash(mi):
    I = flash_intensity()
    return {"type": "sphere", "center": list(FLASH_POS), "radius": FLASH_RADIUS,
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": I / (np.pi * FLASH_RADIUS ** 2)}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}}


def render_scene(m, albedo, cam, lights, spp: int = 32, flash: bool = False, probe: bool = False,
                 seed: int = 7):
    """Render the head (or, with ``probe``, a rough mirror ball at its place) in Mitsuba.

    ``lights``: list of unit directions towards directional lights, each with the flash's
    irradiance at the face; ``flash`` adds the capture flash.  A uniform environment of
    ENV_RADIANCE is always present.  Returns H×W×3 float32 linear RGB.
    """
    mi = _mi()
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
             "sensor": _sensor(mi, cam, spp, seed),
             "env": {"type": "constant", "radiance": {"type": "rgb", "value": ENV_RADIANCE}}}
    if probe:
        scene["ball"] = {"type": "sphere", "center": [0.0, 0.0, DISTANCE_MM], "radius": 60.0,
                         "bsdf": {"type": "roughconductor", "material": "none", "alpha": 0.02,
                                  "distribution": "beckmann"}}
    else:
        scene["head"] = _mesh(mi, m, albedo, skin_bsdf())
    if flash:
        scene["flash"] = _flash(mi)
    E = flash_intensity() / (DISTANCE_MM - 88.0) ** 2
    for i, d in enumerate(lights):
        scene[f"sun{i}"] = {"type": "directional", "direction": list(-np.asarray(d, float)),
                            "irradiance": {"type": "rgb", "value": E}}
    img = mi.render(mi.load_dict(scene), spp=spp)
    return np.asarray(img, np.float32)[..., :3]


def cast_shadow_mask(m, points: np.ndarray, normals: np.ndarray, direction) -> np.ndarray:
    """True where a ray from a surface point towards a directional light hits the mesh
    (Mitsuba ray tests: an outside reference for the shadow maps)."""
    mi = _mi()
    scene = mi.load_dict({"type": "scene", "head": _mesh(mi, m, None, {"type": "diffuse"})})
    d = np.asarray(direction, float)
    out = np.zeros(len(points), bool)
    eps = 0.3  # mm
    for i, (p, n) in enumerate(zip(points, normals)):
        o = p + n * eps
        out[i] = bool(scene.ray_test(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))))
    return out


def main(out_dir: str | None = None, size: int = 128, spp: int = 64):
    import OpenImageIO  # noqa: F401  (encode_image needs it)

    from nodes.io.images import encode_image

    out_dir = out_dir or os.path.join(os.path.dirname(__file__), "sample_capture")
    os.makedirs(out_dir, exist_ok=True)
    m, alb, skin_w = head_mesh()
    cam = camera(size)
    photo = render_scene(m, alb, cam, [], spp, flash=True)
    probe = render_scene(m, alb, cam, [], spp, flash=True, probe=True)
    for name, img in (("photo.exr", photo), ("probe.exr", probe)):
        with open(os.path.join(out_dir, name), "wb") as f:
            f.write(encode_image(img, ".exr", 16))
    m.export(os.path.join(out_dir, "mesh.ply"))
    with open(os.path.join(out_dir, "camera.json"), "w") as f:
        json.dump(cam.model_dump(exclude_none=True), f, indent=1)
    print("wrote", out_dir)


if __name__ == "__main__":
    main()
