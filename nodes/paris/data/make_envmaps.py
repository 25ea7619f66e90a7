"""Environment maps and Mitsuba 3 references for relighting to an environment (issue 26 item 4).

``python nodes/paris/data/make_envmaps.py [NAME …]`` writes (NAME: only those maps, the other references kept)

* ``envmaps/*.exr`` beside this file (``builtin:envmaps/NAME.exr``), 128×64 half-float
  equirectangular maps in LoadEnvironment's convention (nodes/io/environment.py):
  studio, interior, city, courtyard, forest — Blender's CC0 studio-light HDRIs (Debian
  ``blender-data``, /usr/share/blender/datafiles/studiolights/world/, Greg Zaal / HDRI Haven),
  block-averaged; ``sky`` — Mitsuba's ``sunsky`` emitter evaluated per pixel (the sun's disc,
  far smaller than a pixel, integrated on a fine grid and put into its pixel); ``sun`` — the
  same emitter with the sun elsewhere (front left, lower; a tune map: the others tuned on have
  no sun); ``window`` — a dim room with one bright window (analytic);
* ``tests/data/envmap_refs.npz``: Mitsuba renders (``path``, direct light only, 512 spp) of the
  head of make_capture.head_mesh, diffuse with the uniform skin albedo ALBEDO, seen by
  make_capture.camera(SIZE), under an ``envmap`` emitter of each map (to_world: the map's
  frame with no camera, LoadEnvironment's default), float16.

The tests (tests/test_paris_environment.py) compare Render + EnvironmentLights against them.
TUNE maps chose EnvironmentLights' defaults; CHECK maps only check them.
"""
from __future__ import annotations

import functools
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
WORLD_DIR = "/usr/share/blender/datafiles/studiolights/world"
BLENDER = ("studio", "interior", "city", "courtyard", "forest")
TUNE = ("studio", "city", "window", "sun")
CHECK = ("interior", "courtyard", "forest", "sky")
ALBEDO = (0.60, 0.40, 0.31)
SIZE = 64  # pixels of the reference renders
SPP = 512
H, W = 64, 128
REFS = os.path.join(HERE, "..", "..", "..", "tests", "data", "envmap_refs.npz")


def block_average(px: np.ndarray, h: int = H) -> np.ndarray:
    from nodes.paris.environment import downsample

    return downsample(px, 2 * h).astype(np.float32)


def blender_map(name: str) -> np.ndarray:
    from nodes.io.environment import read_hdr

    return block_average(read_hdr(os.path.join(WORLD_DIR, name + ".exr"))[..., :3])


def _mi():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


def _eval(emitter, d_local: np.ndarray) -> np.ndarray:
    """Radiance of Mitsuba's sunsky emitter (its up: +z) towards map-local directions (N×3:
    right, up, centre; taken as sunsky's (x, z, y))."""
    mi = _mi()
    si = mi.SurfaceInteraction3f()
    out = np.empty((len(d_local), 3))
    for i, (x, y, z) in enumerate(d_local):
        si.wi = mi.Vector3f(float(-x), float(-z), float(-y))
        out[i] = np.asarray(emitter.eval(si))[:3]
    return out


#: the tune map ``sun``'s sun, map-local (right, up, centre): front left, 35° up
SUN = (-0.45, 0.57, 0.69)


def sky_map(sun=(0.55, 0.5, -0.67)) -> np.ndarray:
    """Mitsuba's sunsky (Hosek–Wilkie sky + sun) as an H×W map; ``sun``: map-local direction."""
    from nodes.io.environment import local_directions, solid_angles

    mi = _mi()
    s = np.asarray(sun, float) / np.linalg.norm(sun)
    mdir = [float(s[0]), float(s[2]), float(s[1])]
    sky = mi.load_dict({"type": "sunsky", "sun_direction": mdir, "sun_scale": 0.0, "turbidity": 3.0})
    both = mi.load_dict({"type": "sunsky", "sun_direction": mdir, "turbidity": 3.0})
    d = local_directions(H, W).reshape(-1, 3)
    px = _eval(sky, d).reshape(H, W, 3)
    # the sun: ∫ over a 2° cap of (sun + sky − sky), on a fine grid, into the sun's pixel
    a = np.cross(s, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(s, a)
    n, half = 81, np.radians(1.0)
    t = np.linspace(-half, half, n)
    g = s[None, None] + t[:, None, None] * a + t[None, :, None] * b
    g = (g / np.linalg.norm(g, axis=2, keepdims=True)).reshape(-1, 3)
    sun_e = ((_eval(both, g) - _eval(sky, g)) * (2 * half / (n - 1)) ** 2).sum(0)
    th, ph = np.arccos(s[1]), np.arctan2(s[0], s[2])
    y, x = int(th / np.pi * H), int((ph / (2 * np.pi) + 0.5) * W) % W
    px[y, x] += sun_e / solid_angles(H, W)[y, 0]
    return px.astype(np.float32)


def window_map() -> np.ndarray:
    """A dim room (walls 0.03–0.06, a lit floor patch) with one bright, bluish-white window
    (radiance ~6) 40–75° to the right of the map's centre, 5–35° above the horizon."""
    from nodes.io.environment import local_directions

    d = local_directions(H, W)
    el = np.degrees(np.arcsin(np.clip(d[..., 1], -1, 1)))
    az = np.degrees(np.arctan2(d[..., 0], d[..., 2]))
    px = np.empty((H, W, 3))
    px[:] = (0.05, 0.045, 0.04)
    px[el < 0] = (0.03, 0.025, 0.02)
    px += (0.01 * np.cos(np.radians(az)))[..., None]
    win = (az > 40) & (az < 75) & (el > 5) & (el < 35)
    px[win] = (5.5, 6.0, 6.5)
    floor = (az > 20) & (az < 60) & (el < -30) & (el > -60)
    px[floor] += (0.3, 0.28, 0.25)
    return np.clip(px, 0, None).astype(np.float32)


def maps(names=None) -> dict[str, np.ndarray]:
    make = {**{n: functools.partial(blender_map, n) for n in BLENDER}, "sky": sky_map,
            "sun": functools.partial(sky_map, SUN), "window": window_map}
    return {n: f() for n, f in make.items() if names is None or n in names}


def render_reference(px: np.ndarray, spp: int = SPP, size: int = SIZE, seed: int = 3) -> np.ndarray:
    """Mitsuba render of the diffuse head under ``px`` as an ``envmap`` emitter in
    LoadEnvironment's default frame (right +x, up −y, centre +z: to_world columns −right, up,
    centre)."""
    from nodes.paris.data.make_capture import _mesh, _sensor, camera, head_mesh

    mi = _mi()
    m, _, _ = head_mesh(4)
    cam = camera(size)
    T = mi.ScalarTransform4f([[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
             "sensor": _sensor(mi, cam, spp, seed),
             "env": {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(px, np.float32)),
                     "to_world": T},
             "head": _mesh(mi, m, None, {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(ALBEDO)}})}
    return np.asarray(mi.render(mi.load_dict(scene), spp=spp), np.float32)[..., :3]


def main(names=None) -> None:
    """Write the maps ``names`` (all by default) and their references (the others' kept)."""
    from nodes.io.images import encode_image

    out = os.path.join(HERE, "envmaps")
    os.makedirs(out, exist_ok=True)
    refs = dict(np.load(REFS)) if names and os.path.exists(REFS) else {}
    for name, px in maps(names).items():
        with open(os.path.join(out, name + ".exr"), "wb") as f:
            f.write(encode_image(px, ".exr", 32))
        refs[name] = render_reference(px).astype(np.float16)
        print(name, "energy", px.mean(), "ref max", float(refs[name].max()))
    np.savez_compressed(REFS, **refs)
    print("wrote", out, "and", os.path.normpath(REFS))


if __name__ == "__main__":
    import sys

    main(sys.argv[1:] or None)


def lighting(px: np.ndarray, **params):
    """EnvironmentLights(**params) of the map ``px`` in the default frame."""
    from graphkit import Image
    from graphkit.contract import compute_checked
    from nodes.io.environment import EnvironmentFrame
    from nodes.paris.environment import EnvironmentLights

    return compute_checked(EnvironmentLights(EnvironmentLights.Params(**params)),
                           image=Image(np.asarray(px, np.float32)), frame=EnvironmentFrame())


def relight(px: np.ndarray, size: int = SIZE, render: dict | None = None, **params) -> tuple[np.ndarray, np.ndarray]:
    """(Render (more params: ``render``) of the same head under EnvironmentLights(px) — numpy
    reference —, its coverage)."""
    from graphkit.contract import compute_checked
    from nodes.paris.data.make_capture import camera, head_mesh
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import Render

    env = lighting(px, **params)
    m, _, _ = head_mesh(4)
    out = compute_checked(Render(Render.Params(clamp=False, eye_highlights="off", shadow_map_size=4 * size, **(render or {}))), mesh=m, camera=camera(size),
                          material=PhongMaterial(diffuse=ALBEDO, specular=0.0), environment=env)
    return out["image"].pixels, out["coverage"].alpha > 0.5


def skin_psnr(ours: np.ndarray, ref: np.ndarray, cover: np.ndarray) -> float:
    """PSNR (dB) on the head's pixels, one pixel in from its outline, peak = the reference's
    largest value there."""
    from scipy.ndimage import binary_erosion

    m = binary_erosion(cover, iterations=1)
    d = ours[m].astype(np.float64) - ref[m].astype(np.float64)
    return float(10 * np.log10(ref[m].max() ** 2 / np.mean(d * d)))
