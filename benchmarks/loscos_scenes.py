"""Loscos 2000 on the Mitsuba scenes, emittances given vs estimated: the issue-12 table.

    nice .venv/bin/python benchmarks/loscos_scenes.py [--scenes room cornell3 cornell2]
                                                      [--cache /tmp/loscos-scenes]

For each scene and each emittance mode (``scene``: the file's values; ``estimate``: every
light fitted to the photograph, RadiositySolve's ``emittance: estimate``) it runs the
pipeline at the graph's settings (graphs/room_relight.yaml), prints each light's estimated
emittance against the true one, and the PSNR of "A off", "B ×2" and a virtual light against
Mitsuba 3 references (512 spp, rendered from the scene dict), inside the room (pixels that
see a polygon) and over the whole image.  PSNR is of sRGB-encoded values clipped to [0, 1].

builtin:cornell2 is the scene the nodes were tuned on; room and cornell3 are check scenes
(nodes/loscos/data/make_scenes.py states the rule).  References are cached under --cache.
Not part of ``make bench`` (bench_*.py): about 2–3 minutes per scene and mode on 2 cores.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

from graphkit import Context  # noqa: E402
from nodes.common.color import linear_to_srgb  # noqa: E402
from nodes.loscos.radiosity import RadiositySolve, TextureRefine  # noqa: E402
from nodes.loscos.relight import Relight, Unocclude  # noqa: E402
from nodes.loscos.scene import LoadScene  # noqa: E402
from nodes.loscos.textures import ProjectTextures  # noqa: E402

# graphs/room_relight.yaml's settings
RADIOSITY = dict(eps_bf=0.3, eps_bfv=0.03, min_area=0.002, max_level=6)
REFINE = dict(max_level=6, min_area=0.0005, max_rounds=2)
CORNELL2_V = {"name": "V", "center": [0.55, 0.9, -0.45], "size": [0.3, 0.3],
              "normal": [0, -1, 0], "emittance": [40.0, 36.0, 28.0]}


def make_scenes():
    spec = importlib.util.spec_from_file_location(
        "make_scenes", os.path.join(ROOT, "nodes", "loscos", "data", "make_scenes.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def run(cls, params=None, **kw):
    return cls(cls.Params(**(params or {})), Context()).compute(**kw)


def psnr(a, b, mask=None):
    enc = lambda x: np.clip(linear_to_srgb(np.clip(x, 0, None)), 0, 1)  # noqa: E731
    d = (enc(a) - enc(b)) ** 2
    return float(10 * np.log10(1.0 / np.mean(d if mask is None else d[mask])))


def cases(name, ms):
    """(A, B, virtual light) of a scene."""
    if name == "cornell2":
        return "A", "B", CORNELL2_V
    c = ms.CASES[name]
    return c["A"], c["B"], c["virtual"]


def reference(name, case, ms, cache, spp=512):
    """Mitsuba reference (cached .npy): scene dict for room/cornell3, RoomScene for cornell2."""
    path = os.path.join(cache, f"{name}_{case.replace(' ', '_')}_{spp}.npy")
    if os.path.exists(path):
        return np.load(path)
    if name == "cornell2":
        import yaml

        from nodes.loscos import mitsuba_ref as MR
        from nodes.loscos.ports import RoomScene
        from nodes.loscos.relight import quad_from
        from nodes.loscos.scene import DATA, parse_scene

        doc = yaml.safe_load(open(os.path.join(DATA, "cornell2.yaml")))
        sc, _, _ = parse_scene(doc)
        # the fixtures grey, as Relight's default fixture_reflectance
        refl = np.where(np.array([bool(n) for n in sc.light])[:, None], 0.5, sc.reflectance)
        emit_scale = {"A off": {"A": 0.0}, "B x2": {"B": 2.0}}.get(case, {})
        verts, emit, light = sc.verts, sc.emittance, sc.light
        if case == "virtual":
            q = quad_from(CORNELL2_V["center"], CORNELL2_V["size"], CORNELL2_V["normal"])
            verts = np.concatenate([verts, q[None]])
            refl = np.concatenate([refl, np.zeros((1, 3))])
            emit = np.concatenate([emit, [CORNELL2_V["emittance"]]])
            light = light + ["V"]
        sc2 = RoomScene(sc.names + (["V"] if case == "virtual" else []), verts, refl, emit, light)
        c = doc["camera"]
        img = MR.render_photo(sc2, (c["position"], c["look_at"], c["up"]), c["fov_deg"],
                              c["width"], c["height"], spp, seed=11, emit_scale=emit_scale)
    else:
        img = ms.reference(name, case, spp)
    np.save(path, img)
    return img


def pipeline(name, mode):
    t0 = time.perf_counter()
    s = run(LoadScene, {"path": f"builtin:{name}"})
    pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
    out = run(RadiositySolve, dict(RADIOSITY, emittance=mode), scene=s["scene"], projection=pr)
    ref = run(TextureRefine, REFINE, scene=s["scene"], solution=out["solution"], projection=pr)
    un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])["unoccluded"]
    return dict(s, projection=pr, solution=ref, unoccluded=un, lights=out["lights"],
                seconds=time.perf_counter() - t0)


def measure(name, mode, ms, cache):
    A, B, V = cases(name, ms)
    p = pipeline(name, mode)
    sc, sol = p["scene"], p["solution"]
    true = {n: sc.emittance[sc.light.index(n)] for n in sc.light_names}
    pr = p["projection"]
    inside = (pr.pix_poly >= 0).reshape(-1)
    inside[pr.sub_pix[(pr.sub_poly >= 0).any(1)]] = True
    inside = inside.reshape(pr.pix_poly.shape)
    rows = {}
    for case, prm in (("A off", {"light_scale": {A: 0.0}}), ("B x2", {"light_scale": {B: 2.0}}),
                      ("virtual", {"virtual_lights": [V], "eps_bf": 0.3, "eps_bfv": 0.03})):
        ref = reference(name, case, ms, cache)
        img = run(Relight, prm, solution=sol, unoccluded=p["unoccluded"], projection=pr,
                  photo=p["photo"], camera=p["camera"]).pixels
        rows[case] = (psnr(img, ref, inside), psnr(img, ref))
    err = {n: (sol.emit[sol.lights.index(n)] / true[n] - 1) for n in sol.lights}
    return rows, err, sol.emit, true, p["seconds"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=["room", "cornell3", "cornell2"])
    ap.add_argument("--modes", nargs="+", default=["scene", "estimate"])
    ap.add_argument("--cache", default="/tmp/loscos-scenes")
    a = ap.parse_args()
    os.makedirs(a.cache, exist_ok=True)
    ms = make_scenes()
    table = []
    for name in a.scenes:
        for mode in a.modes:
            rows, err, emit, true, sec = measure(name, mode, ms, a.cache)
            table.append((name, mode, rows, err, sec))
            print(f"\n{name} ({'tuned on' if name == 'cornell2' else 'check scene'}), emittance "
                  f"{mode}: preprocess {sec:.0f} s", flush=True)
            for n in true:
                print(f"  light {n:8s} true {np.round(true[n], 2).tolist()}  used "
                      f"{np.round(emit[list(err).index(n)], 2).tolist()}  error "
                      f"{np.round(100 * err[n], 2).tolist()} %")
            for case, (pin, pall) in rows.items():
                print(f"  {case:8s} PSNR inside the room {pin:5.1f} dB, whole image {pall:5.1f} dB")
    print("\n| scene | emittance | A off (room / image) | B ×2 | virtual light | worst light error |")
    print("|---|---|---|---|---|---|")
    for name, mode, rows, err, _ in table:
        cell = lambda c: f"{rows[c][0]:.1f} / {rows[c][1]:.1f}"  # noqa: E731
        worst = max(float(np.abs(v).max()) for v in err.values())
        print(f"| {name} | {'given' if mode == 'scene' else 'estimated'} | {cell('A off')} | "
              f"{cell('B x2')} | {cell('virtual')} | {100 * worst:.2f} % |")


if __name__ == "__main__":
    main()
