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
}


def reference(name: str, s: dict, box: dict, spp: int, cache: str) -> np.ndarray:
    """Mitsuba render of builtin:NAME with the box's faces added as real polygons (cached)."""
    import yaml

    from nodes.loscos import mitsuba_ref as MR
    from nodes.loscos.ports import RoomScene
    from nodes.loscos.relight import box_quads
    from nodes.loscos.scene import DATA

    c = box["center"]
    path = os.path.join(cache, f"virtual_{name}_{c[0]:+.2f}_{c[1]:+.2f}_{c[2]:+.2f}_{spp}.npy")
    if os.path.exists(path):
        return np.load(path)
    sc = s["scene"]
    doc = yaml.safe_load(open(os.path.join(DATA, f"{name}.yaml")))
    cam = doc["camera"]
    refl = np.where(np.array([bool(n) for n in sc.light])[:, None], 0.5, sc.reflectance)
    q = np.asarray(box_quads(box["center"], box["size"], box["rotation_deg"]))
    sc2 = RoomScene(sc.names + [f"virtual.{k}" for k in range(len(q))],
                    np.concatenate([sc.verts, q]),
                    np.concatenate([refl, np.tile(box["reflectance"], (len(q), 1))]),
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
    print("| scene | box centre | incremental (dB) | photo unchanged (dB) | full §4.5 (dB) |")
    print("|---|---|---|---|---|")
    for name in a.scenes:
        d = preprocess(name, a.cache)
        sol, un, pr, s = d["sol"], d["un"], d["pr"], d["s"]
        photo = s["photo"].pixels[:, :, :3]
        inside = (pr.pix_poly >= 0).reshape(-1)
        inside[pr.sub_pix[(pr.sub_poly >= 0).any(1)]] = True
        inside = inside.reshape(pr.pix_poly.shape)
        P = PLACES[name]
        box = {k: v for k, v in P.items() if k != "centers"}
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
                print(f"| {name} | {tuple(c)} | {psnr(img, ref, inside):.1f} | "
                      f"{psnr(photo, ref, inside):.1f} | {full} |", flush=True)


if __name__ == "__main__":
    main()
