"""A furnished box room as a triangle mesh of N triangles: Loscos preprocess time and memory
against N (issue 27 item 3).

    nice .venv/bin/python benchmarks/bench_loscos_mesh.py [--sizes 500 1000 2000]
                                                        [--plot out/loscos_mesh.png]

The room (5 × 3 × 4 m, open towards the camera) holds tables and shelves (trimesh boxes), a
sofa of boxes, lamps (trimesh cylinders), and balls (trimesh icospheres) whose count and
subdivision bring the mesh to about N triangles; a ceiling light and a window light are mesh
parts named in the scene file (emittances given).  Each size is written as OBJ + scene YAML and
photographed by Mitsuba 3 (64×48 px, 16 spp: the photo only feeds the textures), then run in a
fresh process — ProjectTextures, RadiositySolve, TextureRefine, Unocclude, ``--backend
embree`` — which reports CPU seconds and its peak memory (ru_maxrss).  The box faces pair back
into parallelograms, the curved parts stay triangles (the polygons count both).  ``--plot``
writes CPU seconds and peak memory against the triangle count (PNG).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

SETTINGS = {"RadiositySolve": dict(eps_bf=0.3, eps_bfv=0.03, min_area=0.01, max_level=4),
            "TextureRefine": dict(max_level=4, min_area=0.005, max_rounds=1)}


def room_parts(n_tri: int, seed: int = 0) -> dict:
    """{part: (vertices, faces, rgb)}: a furnished room of about n_tri triangles."""
    import trimesh
    from trimesh import creation as C

    rng = np.random.default_rng(seed)
    W, H, D = 5.0, 3.0, 4.0

    def quad(a, b, c, d):
        return np.array([a, b, c, d], float), np.array([[0, 1, 2], [0, 2, 3]])

    parts = {  # walls facing inwards (counter-clockwise from inside)
        "floor": quad([0, 0, 0], [0, 0, -D], [W, 0, -D], [W, 0, 0]) + ([0.6, 0.55, 0.5],),
        "ceiling": quad([0, H, 0], [W, H, 0], [W, H, -D], [0, H, -D]) + ([0.8, 0.8, 0.8],),
        "back": quad([0, 0, -D], [0, H, -D], [W, H, -D], [W, 0, -D]) + ([0.7, 0.7, 0.65],),
        "left": quad([0, 0, 0], [0, H, 0], [0, H, -D], [0, 0, -D]) + ([0.6, 0.3, 0.25],),
        "right": quad([W, 0, 0], [W, 0, -D], [W, H, -D], [W, H, 0]) + ([0.3, 0.45, 0.6],),
        "lamp": quad([2.2, H - 1e-3, -1.6], [2.8, H - 1e-3, -1.6], [2.8, H - 1e-3, -2.2],
                     [2.2, H - 1e-3, -2.2]) + ([0.5, 0.5, 0.5],),
        "window": quad([1e-3, 1.2, -1.0], [1e-3, 1.2, -2.0], [1e-3, 2.2, -2.0],
                       [1e-3, 2.2, -1.0]) + ([0.5, 0.5, 0.5],),
    }
    meshes = []

    def add(m, name, rgb):
        meshes.append((name, m, rgb))

    for k, (x, z, w, d, h) in enumerate([(1.0, -1.2, 1.4, 0.8, 0.75), (3.6, -3.2, 1.6, 0.5, 1.8),
                                          (3.8, -1.0, 1.2, 0.9, 0.45)]):
        add(C.box([w, h, d], trimesh.transformations.translation_matrix([x, h / 2, z])),
            f"furniture{k}", rng.uniform(0.2, 0.8, 3))
    for k, (x, z) in enumerate([(0.6, -3.4), (4.5, -0.5)]):
        add(C.cylinder(0.12, 1.5, sections=32,
                       transform=trimesh.transformations.translation_matrix([x, 0.75, z])
                       @ trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])),
            f"lampstand{k}", [0.3, 0.3, 0.3])
    base = sum(len(m.faces) for _, m, _ in meshes) + 2 * len(parts)
    left = max(n_tri - base, 80)
    sub = int(np.clip(np.floor(np.log(max(left / 8, 20) / 20) / np.log(4)), 0, 4))
    per = 20 * 4 ** sub
    for k in range(max(1, int(round(left / per)))):
        r = rng.uniform(0.08, 0.2)
        x, z = rng.uniform(0.4, W - 0.4), rng.uniform(-D + 0.4, -0.4)
        y = r + (0.75 if (0.3 < x < 1.7 and -1.6 < z < -0.8) else 0.0)
        add(C.icosphere(sub, r).apply_translation([x, y, z]), f"ball{k}", rng.uniform(0.2, 0.9, 3))
    for name, m, rgb in meshes:
        parts[name] = (np.asarray(m.vertices), np.asarray(m.faces), np.asarray(rgb, float))
    return parts


def write_scene(n_tri: int, folder: str) -> tuple[str, int]:
    """OBJ + MTL + scene YAML + Mitsuba photo for a room of about n_tri triangles."""
    import yaml

    from nodes.io.images import encode_image
    from nodes.loscos import mitsuba_ref as MR
    from nodes.loscos.scene import parse_scene

    parts = room_parts(n_tri)
    lines, mtl, base, n = ["mtllib room.mtl"], [], 1, 0
    for name, (V, F, rgb) in parts.items():
        lines += [f"o {name}", f"usemtl {name}"]
        lines += ["v " + " ".join(repr(float(x)) for x in p) for p in V]
        lines += ["f " + " ".join(str(base + i) for i in f) for f in F]
        mtl += [f"newmtl {name}", "Kd " + " ".join(repr(float(x)) for x in rgb)]
        base += len(V)
        n += len(F)
    open(os.path.join(folder, "room.obj"), "w").write("\n".join(lines) + "\n")
    open(os.path.join(folder, "room.mtl"), "w").write("\n".join(mtl) + "\n")
    cam = {"width": 64, "height": 48, "fov_deg": 70, "position": [2.5, 1.5, 1.5],
           "look_at": [2.5, 1.2, -2.0], "up": [0, 1, 0]}
    doc = {"loscos_scene": 1, "camera": cam, "photo": "photo.exr",
           "meshes": [{"file": "room.obj", "parts": {k: [float(x) for x in v[2]]
                                                     for k, v in parts.items()}}],
           "lights": [{"name": "lamp", "emittance": [60.0, 55.0, 45.0]},
                      {"name": "window", "emittance": [20.0, 24.0, 30.0]}]}
    sc, _, _ = parse_scene(doc, base_dir=folder)
    img = MR.render_photo(sc, (cam["position"], cam["look_at"], cam["up"]), cam["fov_deg"],
                          cam["width"], cam["height"], 16, seed=3)
    with open(os.path.join(folder, "photo.exr"), "wb") as f:
        f.write(encode_image(np.asarray(img, np.float32), ".exr", 16))
    with open(os.path.join(folder, "scene.yaml"), "w") as f:
        yaml.safe_dump(doc, f)
    return os.path.join(folder, "scene.yaml"), n


def run_one(path: str) -> dict:
    """The preprocess of one scene file in this process: CPU seconds, polygons, peak memory."""
    import resource

    from graphkit import Context
    from nodes.common import rays
    from nodes.loscos.geometry import is_triangle
    from nodes.loscos.radiosity import RadiositySolve, TextureRefine
    from nodes.loscos.relight import Unocclude
    from nodes.loscos.scene import LoadScene
    from nodes.loscos.textures import ProjectTextures

    def run(cls, params=None, **kw):
        return cls(cls.Params(**(params or {})), Context()).compute(**kw)

    c0 = time.process_time()
    with rays.using("embree"):
        s = run(LoadScene, {"path": path})
        c1 = time.process_time()
        pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
        sol = run(RadiositySolve, SETTINGS["RadiositySolve"], scene=s["scene"],
                  projection=pr)["solution"]
        ref = run(TextureRefine, SETTINGS["TextureRefine"], scene=s["scene"], solution=sol,
                  projection=pr)
        run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])
    c2 = time.process_time()
    tri = is_triangle(s["scene"].verts)
    return {"load_s": c1 - c0, "preprocess_s": c2 - c1, "polygons": int(len(tri)),
            "triangle_polygons": int(tri.sum()), "links": int(len(ref.recv)),
            "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["triangles"] for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    ax[0].loglog(n, [r["preprocess_s"] for r in rows], "o-")
    ax[0].set(xlabel="triangles in the mesh", ylabel="preprocess CPU s", title="time")
    ax[1].loglog(n, [r["maxrss_mb"] for r in rows], "o-")
    ax[1].set(xlabel="triangles in the mesh", ylabel="peak memory MB", title="ru_maxrss")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", type=int, default=[500, 1000, 2000])
    ap.add_argument("--plot", default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child: one scene file
    a = ap.parse_args()
    if a.one:
        print(json.dumps(run_one(a.one)))
        return
    rows = []
    for n in a.sizes:
        with tempfile.TemporaryDirectory() as d:
            path, tris = write_scene(n, d)
            r = subprocess.run([sys.executable, __file__, "--one", path], capture_output=True,
                               text=True)
            if r.returncode:
                print(f"{tris} triangles: failed ({r.stderr.strip().splitlines()[-1:]})")
                continue
            row = dict(json.loads(r.stdout.strip().splitlines()[-1]), triangles=tris)
        rows.append(row)
        print(f"{tris:6d} triangles → {row['polygons']} polygons ({row['triangle_polygons']} "
              f"triangles): preprocess {row['preprocess_s']:.1f} s CPU, {row['links']} links, "
              f"peak {row['maxrss_mb']:.0f} MB; load {os.getloadavg()[0]:.1f}", flush=True)
    if a.plot and rows:
        os.makedirs(os.path.dirname(os.path.abspath(a.plot)), exist_ok=True)
        plot(rows, a.plot)
        print("wrote", a.plot)


if __name__ == "__main__":
    main()
