"""Virtual objects against Mitsuba (issue 27 item 5): a box really in the room, three places.

    nice .venv/bin/python benchmarks/loscos_virtual_fidelity.py [--scenes cornell2 room] [--spp 256]

For each scene, the preprocess of bench_loscos_virtual.py (room_relight's settings, cached),
then a box inserted with VirtualSession (the studio's incremental path) and dragged to three
places; each image is compared with Mitsuba 3 rendering the same room with the box's six faces
as real polygons (so the light it blocks, its shadows and its reflected light are all in the
reference), inside the room (pixels that see a polygon), as PSNR of sRGB values clipped to
[0, 1] (as benchmarks/loscos_scenes.py).  Also: the unchanged photograph against the same
reference (what the box changes), and Relight's full §4.5 path (relight.relight_virtual) at the
first place.  builtin:cornell2 is the tuning scene, builtin:room the check scene.  References
are cached under --cache (.npy).  Not part of ``make bench``: minutes per scene (Mitsuba).

Clustered rooms (past radiosity.CLUSTER_ABOVE polygons: cluster links, which the box must
block too): ``furnished`` (about 2000 triangles; the tuning room) and ``furnished_check`` (about
3000, another layout, a 160×120 photo; the check room), bench_loscos_virtual.py's.  Also the
box's shadow: the pixels (inside, not showing the box, above DARK × the median) where Mitsuba
with the box is below SHADOW × Mitsuba without it (both at --spp, smoothed 3×3), their mean
luminance in our image and in Mitsuba's, each as a fraction of Mitsuba's without the box there.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(__file__))

from bench_loscos_virtual import preprocess  # noqa: E402
from loscos_scenes import psnr  # noqa: E402

from nodes.common import rays  # noqa: E402

#: per scene: three places of one box (centre, size, rotation about +y, reflectance)
PLACES = {
    "cornell2": dict(size=(0.3, 0.3, 0.3), rotation_deg=20, reflectance=(0.8, 0.4, 0.1),
                     centers=[(-0.5, -0.85, 0.55), (-0.7, -0.85, 0.75), (0.5, -0.85, -0.5)]),
    "room": dict(size=(0.4, 0.4, 0.4), rotation_deg=15, reflectance=(0.2, 0.4, 0.75),
                 centers=[(-1.0, 0.2, 0.6), (-0.4, 0.2, 0.9), (0.3, 0.975, -0.5)]),
    "furnished": dict(size=(0.4, 0.4, 0.4), rotation_deg=15, reflectance=(0.2, 0.4, 0.75),
                      centers=[(0.9, 0.2, -2.3), (2.2, 0.2, -1.9), (1.3, 0.95, -0.9)]),
    "furnished_check": dict(size=(0.4, 0.4, 0.4), rotation_deg=25, reflectance=(0.75, 0.4, 0.2),
                            centers=[(2.0, 0.2, -2.2), (1.8, 0.2, -3.0), (0.8, 0.95, -1.1)]),
}
SHADOW = 0.8  # a pixel is in the box's shadow where the box takes a fifth of its light…
DARK = 0.2  # …and it is not among the room's darkest (where Mitsuba's noise decides)


def scene_doc(name: str, cache: str) -> dict:
    """The scene file of builtin:NAME or of bench_loscos_virtual's furnished room NAME."""
    import yaml

    from bench_loscos_virtual import FURNISHED
    from nodes.loscos.scene import DATA

    path = (os.path.join(cache, name, "scene.yaml") if name in FURNISHED
            else os.path.join(DATA, f"{name}.yaml"))
    return yaml.safe_load(open(path))


def shadow(img, with_box, without, inside, box_px):
    """(pixels, our mean, Mitsuba's mean): the box's shadow (see the module docstring), the
    means of luminance relative to Mitsuba's without the box."""
    from scipy.ndimage import uniform_filter

    lum = lambda x: uniform_filter(x @ [0.2126, 0.7152, 0.0722], 3)  # noqa: E731
    a, b, c = lum(img), lum(with_box), lum(without)
    m = inside & ~box_px & (b < SHADOW * c) & (c > DARK * np.median(c[inside]))
    return int(m.sum()), float(a[m].sum() / c[m].sum()), float(b[m].sum() / c[m].sum())


def box_pixels(S, name: str) -> np.ndarray:
    """(H, W) bool: pixels where a camera ray meets thing ``name`` before the room."""
    from nodes.loscos.textures import rays_at
    from nodes.loscos.virtual import _first_triangle

    H, W = S.plan.photo.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W]
    o, d = rays_at(S.camera, xs.ravel() + 0.5, ys.ravel() + 0.5)
    _, t = _first_triangle(o, d, S.things[name].thing.tris)
    return (t < S.room_depth.min(2).reshape(-1)).reshape(H, W)


def reference(name: str, s: dict, box: dict, spp: int, cache: str) -> np.ndarray:
    """Mitsuba render of builtin:NAME with the box's faces added as real polygons (cached)."""
    from nodes.loscos import mitsuba_ref as MR
    from nodes.loscos.ports import RoomScene
    from nodes.loscos.relight import box_quads

    c = box["center"] if box else (0, 0, 0)
    path = os.path.join(cache, f"virtual_{name}_{c[0]:+.2f}_{c[1]:+.2f}_{c[2]:+.2f}_{spp}"
                               f"{'' if box else '_nobox'}.npy")
    if os.path.exists(path):
        return np.load(path)
    sc = s["scene"]
    cam = scene_doc(name, cache)["camera"]
    refl = np.where(np.array([bool(n) for n in sc.light])[:, None], 0.5, sc.reflectance)
    q = (np.asarray(box_quads(box["center"], box["size"], box["rotation_deg"])) if box
         else np.zeros((0, 4, 3)))
    sc2 = RoomScene(sc.names + [f"virtual.{k}" for k in range(len(q))],
                    np.concatenate([sc.verts, q]),
                    np.concatenate([refl, np.tile(box["reflectance"] if box else np.zeros(3), (len(q), 1))]),
                    np.concatenate([sc.emittance, np.zeros((len(q), 3))]),
                    list(sc.light) + [""] * len(q))
    img = MR.render_photo(sc2, (cam["position"], cam["look_at"], cam.get("up", [0, 1, 0])),
                          cam["fov_deg"], cam["width"], cam["height"], spp, seed=11)
    os.makedirs(cache, exist_ok=True)
    np.save(path, img)
    return img


def main():
    from nodes.loscos import hierarchy as HR
    from nodes.loscos.relight import VirtualBox, relight_virtual, virtual_polygons
    from nodes.loscos.virtual import VirtualSession, box_thing

    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=["cornell2", "room"])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--cache", default=".graphkit-cache/bench")
    ap.add_argument("--no-peer", action="store_true", help="skip Relight's full §4.5 path")
    a = ap.parse_args()
    print("| scene | box centre | incremental (dB) | photo unchanged (dB) | full §4.5 (dB) | "
          "shadow px | shadow ours | shadow Mitsuba |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.scenes:
        d = preprocess(name, a.cache)
        sol, un, pr, s = d["sol"], d["un"], d["pr"], d["s"]
        photo = s["photo"].pixels[:, :, :3]
        inside = (pr.pix_poly >= 0).reshape(-1)
        inside[pr.sub_pix[(pr.sub_poly >= 0).any(1)]] = True
        inside = inside.reshape(pr.pix_poly.shape)
        P = PLACES[name]
        box = {k: v for k, v in P.items() if k != "centers"}
        without = reference(name, s, None, a.spp, a.cache)
        with rays.using("embree"):
            S = VirtualSession(sol, un, pr, photo, s["camera"], names=s["scene"].names)
            for i, c in enumerate(P["centers"]):
                b = dict(box, center=c)
                img = S.insert(box_thing("box", **b)) if i == 0 else S.move("box", to=(c[0], c[1] - b["size"][1] / 2, c[2]))
                ref = reference(name, s, b, a.spp, a.cache)
                full = ""
                if i == 0 and not a.no_peer:
                    prm = HR.RefineParams(0.1, 0.01, 2e-3, 6, 4, 3, 0)
                    vp = virtual_polygons([], [VirtualBox(name="box", **b)])
                    im2, _ = relight_virtual(sol, un, pr, photo, s["camera"], sol.emit, vp, prm, 3, 1e-6)
                    full = f"{psnr(im2, ref, inside):.1f}"
                n, ours, theirs = shadow(img, ref, without, inside, box_pixels(S, "box"))
                print(f"| {name} | {tuple(c)} | {psnr(img, ref, inside):.1f} | "
                      f"{psnr(photo, ref, inside):.1f} | {full} | {n} | {ours:.3f} | "
                      f"{theirs:.3f} |", flush=True)


if __name__ == "__main__":
    main()
