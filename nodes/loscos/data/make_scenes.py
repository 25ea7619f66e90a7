"""Build the check scenes builtin:room and builtin:cornell3 — Mitsuba 3 scene dicts, converted
to scene files by nodes/loscos/mitsuba_scene.py — and photograph them with Mitsuba.

Run from the repository root:  nice .venv/bin/python nodes/loscos/data/make_scenes.py
Writes nodes/loscos/data/{room,cornell3}.yaml (emittances given) and {room,cornell3}.exr (the
"photograph": a Mitsuba 3 path-traced render of the scene dict itself, linear radiance,
128×128, float16 EXR), and cornell3's references for the oracle test,
cornell3_{A_off,B_x2,virtual}.exr (512 spp, seed 11; rendering them in the test would cost
about 30 s).  benchmarks/loscos_scenes.py renders the room's (slow: a closed room).

* ``room`` (not a Cornell box): a 4 × 2.6 × 3.5 m room, closed, camera inside; a bluish
  window-like emitter on the back wall (1.2 × 1.0 m), a warm pendant lamp (0.4 × 0.4 m, five
  times the radiance), a table on four legs, a cabinet, a blue side wall, a wooden floor.
* ``cornell3``: Mitsuba's ``cornell_box()`` walls and boxes with its light replaced by two
  others: a small strong warm one at the back right and a larger cyan one at the front left.

Tuning rule: every parameter and threshold of the Loscos nodes was chosen on
builtin:cornell2 (make_cornell2.py).  These two scenes are check scenes only: nothing was
tuned on them; their numbers are measured, reported and asserted, never used to pick a value.
Each scene lists its relighting cases (``CASES``): light A off, light B ×2, a virtual light;
:func:`reference` renders each case's Mitsuba reference from the scene dict.  Every light
fixture is grey (diffuse 0.5), Relight's default ``fixture_reflectance``.
"""
from __future__ import annotations

import hashlib
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.abspath(os.path.join(HERE, "..", "..", "..")))

SIZE = 128
SPP = 512
GREY = [0.5, 0.5, 0.5]


def _mi():
    from nodes.loscos.mitsuba_ref import set_variant

    return set_variant()


def _T(M):
    return _mi().ScalarTransform4f(np.asarray(M, float).tolist())


def rect(center, u, v):
    """to_world of Mitsuba's rectangle [-1,1]² onto the parallelogram centre ± u ± v (normal
    u × v)."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    n = np.cross(u, v)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = u, v, n / np.linalg.norm(n), center
    return _T(M)


def cube(center, half):
    M = np.diag(list(half) + [1.0])
    M[:3, 3] = center
    return _T(M)


def diffuse(rgb):
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(rgb)}}


def area(radiance):
    return {"type": "area", "radiance": {"type": "rgb", "value": list(radiance)}}


def sensor(origin, target, fov, spp=SPP, size=SIZE):
    mi = _mi()
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"}}


def room(spp=SPP):
    """The room scene dict (metres; radiance in W/(m² sr))."""
    W, H, D = 2.0, 2.6, 1.75  # half width, height, half depth
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": -1},
         "sensor": sensor([0.6, 1.45, 1.65], [-0.3, 1.1, -D], 80.0, spp),
         "plaster": diffuse([0.72, 0.70, 0.66]), "blue": diffuse([0.25, 0.38, 0.60]),
         "wood": diffuse([0.55, 0.38, 0.22]), "ceiling-white": diffuse([0.80, 0.80, 0.80]),
         "dark-wood": diffuse([0.35, 0.22, 0.12]), "sage": diffuse([0.30, 0.50, 0.30]),
         "fixture": diffuse(GREY)}
    ref = lambda k: {"type": "ref", "id": k}  # noqa: E731
    d["floor"] = {"type": "rectangle", "to_world": rect([0, 0, 0], [W, 0, 0], [0, 0, -D]),
                  "bsdf": ref("wood")}
    d["ceiling"] = {"type": "rectangle", "to_world": rect([0, H, 0], [W, 0, 0], [0, 0, D]),
                    "bsdf": ref("ceiling-white")}
    d["back"] = {"type": "rectangle", "to_world": rect([0, H / 2, -D], [W, 0, 0], [0, H / 2, 0]),
                 "bsdf": ref("plaster")}
    d["front"] = {"type": "rectangle", "to_world": rect([0, H / 2, D], [-W, 0, 0],
                                                        [0, H / 2, 0]), "bsdf": ref("plaster")}
    d["left"] = {"type": "rectangle", "to_world": rect([-W, H / 2, 0], [0, 0, -D],
                                                       [0, H / 2, 0]), "bsdf": ref("plaster")}
    d["right"] = {"type": "rectangle", "to_world": rect([W, H / 2, 0], [0, 0, D],
                                                        [0, H / 2, 0]), "bsdf": ref("blue")}
    d["table-top"] = {"type": "cube", "to_world": cube([0.3, 0.75, -0.5], [0.6, 0.025, 0.4]),
                      "bsdf": ref("dark-wood")}
    for i, (sx, sz) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        d[f"leg-{i}"] = {"type": "cube", "to_world": cube([0.3 + 0.55 * sx, 0.3625,
                                                           -0.5 + 0.35 * sz],
                                                          [0.025, 0.3625, 0.025]),
                         "bsdf": ref("dark-wood")}
    d["cabinet"] = {"type": "cube", "to_world": cube([-1.5, 0.5, -1.2], [0.35, 0.5, 0.25]),
                    "bsdf": ref("sage")}
    d["window"] = {"type": "rectangle", "to_world": rect([-0.5, 1.55, -D + 0.01], [0.6, 0, 0],
                                                         [0, 0.5, 0]),
                   "bsdf": ref("fixture"), "emitter": area([3.0, 3.6, 4.4])}
    d["lamp"] = {"type": "rectangle", "to_world": rect([0.8, 2.2, -0.6], [0.2, 0, 0],
                                                       [0, 0, 0.2]),
                 "bsdf": ref("fixture"), "emitter": area([22.0, 15.0, 7.0])}
    return d


def cornell3(spp=SPP):
    """Mitsuba's Cornell box with its light replaced by two lights (warm/strong, cyan/wide)."""
    d = dict(_mi().cornell_box())
    d.pop("light")
    d["sensor"] = dict(d["sensor"], sampler={"type": "independent", "sample_count": spp},
                       film={"type": "hdrfilm", "width": SIZE, "height": SIZE,
                             "rfilter": {"type": "box"}, "pixel_format": "rgb"})
    d["fixture"] = diffuse(GREY)
    down = lambda c, a, b: rect(c, [a, 0, 0], [0, 0, b])  # noqa: E731  facing −y
    d["warm"] = {"type": "rectangle", "to_world": down([0.35, 0.99, -0.45], 0.15, 0.125),
                 "bsdf": {"type": "ref", "id": "fixture"}, "emitter": area([30.0, 20.0, 9.0])}
    d["cyan"] = {"type": "rectangle", "to_world": down([-0.45, 0.99, 0.4], 0.22, 0.17),
                 "bsdf": {"type": "ref", "id": "fixture"}, "emitter": area([5.0, 11.0, 12.0])}
    return d


SCENES = {"room": room, "cornell3": cornell3}
# relighting cases: (label, Relight params); A / B are the scene's first / second light
CASES = {
    "room": {"A": "window", "B": "lamp",
             "virtual": {"name": "V", "center": [-0.6, 2.1, 0.6], "size": [0.3, 0.3],
                         "normal": [0, -1, 0], "emittance": [45.0, 42.0, 34.0]}},
    "cornell3": {"A": "warm", "B": "cyan",
                 "virtual": {"name": "V", "center": [-0.45, 0.9, -0.5], "size": [0.3, 0.3],
                             "normal": [0, -1, 0], "emittance": [36.0, 36.0, 40.0]}},
}


def relit(name: str, case: str, spp: int = SPP) -> dict:
    """The scene dict for one relighting case: 'A off', 'B x2', 'virtual' (or 'photo')."""
    from nodes.loscos.relight import quad_from

    d = SCENES[name](spp)
    c = CASES[name]
    if case == "A off":
        d[c["A"]] = {k: v for k, v in d[c["A"]].items() if k != "emitter"}
    elif case == "B x2":
        em = d[c["B"]]["emitter"]
        d[c["B"]] = dict(d[c["B"]], emitter=area(2 * np.asarray(em["radiance"]["value"])))
    elif case == "virtual":
        v = c["virtual"]
        q = quad_from(v["center"], v["size"], v["normal"])
        o, u, w = q[0], q[1] - q[0], q[3] - q[0]
        d["virtual-light"] = {"type": "rectangle", "to_world": rect(o + (u + w) / 2, u / 2, w / 2),
                              "bsdf": diffuse([0, 0, 0]),
                              "emitter": area(np.asarray(v["emittance"]) / np.pi)}
    elif case != "photo":
        raise ValueError(case)
    return d


def render(d: dict, spp: int, seed: int = 0) -> np.ndarray:
    """Linear-radiance RGB (H,W,3) float32 render of a scene dict."""
    from nodes.loscos.mitsuba_ref import set_variant

    mi = set_variant()
    return np.array(mi.render(mi.load_dict(d), spp=spp, seed=seed), np.float32)[:, :, :3]


def reference(name: str, case: str, spp: int, seed: int = 11) -> np.ndarray:
    return render(relit(name, case, spp), spp, seed)


REFERENCES = {"cornell3": ("A off", "B x2", "virtual")}  # committed: the oracle test reads them


def reference_file(name: str, case: str) -> str:
    return os.path.join(HERE, f"{name}_{case.replace(' ', '_')}.exr")


def main(names=None):
    from nodes.io.images import encode_image
    from nodes.loscos.mitsuba_ref import set_variant
    from nodes.loscos.mitsuba_scene import write_scene_file

    set_variant()
    for name in names or SCENES:
        d = SCENES[name]()
        data = encode_image(render(d, SPP, seed=1), ".exr", 16)
        with open(os.path.join(HERE, f"{name}.exr"), "wb") as f:
            f.write(data)
        write_scene_file(d, os.path.join(HERE, f"{name}.yaml"), photo=f"{name}.exr",
                         photo_sha256=hashlib.sha256(data).hexdigest())
        print("wrote", f"{name}.yaml", f"{name}.exr")
        for case in REFERENCES.get(name, ()):
            with open(reference_file(name, case), "wb") as f:
                f.write(encode_image(reference(name, case, SPP), ".exr", 16))
            print("wrote", os.path.basename(reference_file(name, case)))


if __name__ == "__main__":
    main(sys.argv[1:] or None)
