"""A furnished box room as a triangle mesh of N triangles: Loscos preprocess time and memory
against N (issue 27 item 3).

    nice .venv/bin/python benchmarks/bench_loscos_mesh.py [--sizes 1000 2000 5000 10000 20000 50000]
        [--plot out/loscos_mesh.png] [--cap-cpu 600] [--cap-mb 5000] [--peer 1000]

The room (5 × 3 × 4 m, open towards the camera) holds tables and shelves (trimesh boxes), a
sofa of boxes, lamps (trimesh cylinders), and balls (trimesh icospheres, at most 1,280
triangles each, standing on the floor or on the furniture) whose count brings the mesh to
about N triangles (50k: 39 balls); a ceiling light and a window light are mesh parts named
in the scene file (emittances given).  Each size is written as OBJ + scene YAML and
photographed by Mitsuba 3 (``--photo``: 64×48 px, 16 spp, the photo only feeds the textures),
then run in a fresh process with ``--backend embree`` — LoadScene, ProjectTextures, RadiositySolve,
TextureRefine, Unocclude (the preprocess) and one Relight (the lamp off) — which reports each
node's CPU and wall seconds and the peak memory (ru_maxrss) after it.  The child is stopped past
``--cap-cpu`` CPU seconds (RLIMIT_CPU), ``--cap-wall`` wall seconds or ``--cap-mb`` resident MB
(sampled every 0.2 s): that size is reported as infeasible, with the node it was in.  The
box faces pair back into parallelograms, the curved parts stay triangles (the polygons count
both).  ``--plot`` writes CPU seconds (total and per node) and peak memory against the
triangle count, log-log (PNG); the growth exponent between sizes is printed.

``--peer N``: at size N, the relit image's PSNR (inside the room) against Mitsuba's 1024-spp
render of the same relit scene (seed 23), and the spp and CPU seconds Mitsuba's path tracer
needs to reach that PSNR (1, 2, 4, … spp, seed 5), as bench_loscos_speed.py's peer.
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
        return np.array([a, b, c, d], float), np.array([[0, 2, 1], [0, 3, 2]])  # (a, c, b): normal inwards

    parts = {  # walls facing inwards (counter-clockwise from inside)
        "floor": quad([0, 0, 0], [0, 0, -D], [W, 0, -D], [W, 0, 0]) + ([0.6, 0.55, 0.5],),
        "ceiling": quad([0, H, 0], [W, H, 0], [W, H, -D], [0, H, -D]) + ([0.8, 0.8, 0.8],),
        "back": quad([0, 0, -D], [0, H, -D], [W, H, -D], [W, 0, -D]) + ([0.7, 0.7, 0.65],),
        "left": quad([0, 0, 0], [0, H, 0], [0, H, -D], [0, 0, -D]) + ([0.6, 0.3, 0.25],),
        "right": quad([W, 0, 0], [W, 0, -D], [W, H, -D], [W, H, 0]) + ([0.3, 0.45, 0.6],),
        "lamp": quad([2.2, H - 1e-3, -1.6], [2.8, H - 1e-3, -1.6], [2.8, H - 1e-3, -2.2],
                     [2.2, H - 1e-3, -2.2]) + ([0.5, 0.5, 0.5],),
        "window": quad([1e-3, 1.2, -1.0], [1e-3, 2.2, -1.0], [1e-3, 2.2, -2.0],
                       [1e-3, 1.2, -2.0]) + ([0.5, 0.5, 0.5],),
    }
    meshes = []

    def add(m, name, rgb):
        meshes.append((name, m, rgb))

    furniture = [(1.0, -1.2, 1.4, 0.8, 0.75), (3.6, -3.2, 1.6, 0.5, 1.8), (3.8, -1.0, 1.2, 0.9, 0.45)]
    for k, (x, z, w, d, h) in enumerate(furniture):
        add(C.box([w, h, d], trimesh.transformations.translation_matrix([x, h / 2, z])),
            f"furniture{k}", rng.uniform(0.2, 0.8, 3))
    stands = [(0.6, -3.4), (4.5, -0.5)]
    for k, (x, z) in enumerate(stands):
        add(C.cylinder(0.12, 1.5, sections=32,
                       transform=trimesh.transformations.translation_matrix([x, 0.75, z])
                       @ trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])),
            f"lampstand{k}", [0.3, 0.3, 0.3])
    base = sum(len(m.faces) for _, m, _ in meshes) + 2 * len(parts)
    left = max(n_tri - base, 80)
    sub = int(np.clip(np.floor(np.log(max(left / 8, 20) / 20) / np.log(4)), 0, 3))
    per = 20 * 4 ** sub
    for k in range(max(1, int(round(left / per)))):
        r = rng.uniform(0.08, 0.2)
        x, z = rng.uniform(0.4, W - 0.4), rng.uniform(-D + 0.4, -0.4)
        while any(np.hypot(x - a, z - b) < r + 0.13 for a, b in stands):
            x, z = rng.uniform(0.4, W - 0.4), rng.uniform(-D + 0.4, -0.4)
        y = r + max([h for a, b, w, d, h in furniture
                     if abs(x - a) < w / 2 and abs(z - b) < d / 2], default=0.0)
        add(C.icosphere(sub, r).apply_translation([x, y, z]), f"ball{k}", rng.uniform(0.2, 0.9, 3))
    for name, m, rgb in meshes:
        parts[name] = (np.asarray(m.vertices), np.asarray(m.faces), np.asarray(rgb, float))
    return parts


def write_scene(n_tri: int, folder: str, photo=(64, 48, 16)) -> tuple[str, int]:
    """OBJ + MTL + scene YAML + Mitsuba photo (width, height, spp) for a room of about n_tri
    triangles."""
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
    cam = {"width": photo[0], "height": photo[1], "fov_deg": 70, "position": [2.5, 1.5, 1.5],
           "look_at": [2.5, 1.2, -2.0], "up": [0, 1, 0]}
    doc = {"loscos_scene": 1, "camera": cam, "photo": "photo.exr",
           "meshes": [{"file": "room.obj", "parts": {k: [float(x) for x in v[2]]
                                                     for k, v in parts.items()}}],
           "lights": [{"name": "lamp", "emittance": [60.0, 55.0, 45.0]},
                      {"name": "window", "emittance": [20.0, 24.0, 30.0]}]}
    sc, _, _ = parse_scene(doc, base_dir=folder)
    img = MR.render_photo(sc, (cam["position"], cam["look_at"], cam["up"]), cam["fov_deg"],
                          cam["width"], cam["height"], photo[2], seed=3)
    with open(os.path.join(folder, "photo.exr"), "wb") as f:
        f.write(encode_image(np.asarray(img, np.float32), ".exr", 16))
    with open(os.path.join(folder, "scene.yaml"), "w") as f:
        yaml.safe_dump(doc, f)
    return os.path.join(folder, "scene.yaml"), n




NODES = ("LoadScene", "ProjectTextures", "RadiositySolve", "TextureRefine", "Unocclude", "Relight")
PREPROCESS = NODES[1:5]


def run_one(path: str, relit_out: str | None = None) -> None:
    """The nodes on one scene file in this process, a JSON line after each (CPU seconds, peak
    MB so far), then the polygons and links; with ``relit_out``, the relit image saved there."""
    import resource

    from graphkit import Context
    from nodes.common import rays
    from nodes.loscos.geometry import is_triangle
    from nodes.loscos.radiosity import RadiositySolve, TextureRefine
    from nodes.loscos.relight import Relight, Unocclude
    from nodes.loscos.scene import LoadScene
    from nodes.loscos.textures import ProjectTextures

    def run(cls, params=None, **kw):
        c, w = time.process_time(), time.perf_counter()
        out = cls(cls.Params(**(params or {})), Context()).compute(**kw)
        print(json.dumps({"node": cls.__name__, "cpu_s": time.process_time() - c,
                          "wall_s": time.perf_counter() - w,
                          "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}),
              flush=True)
        return out

    with rays.using("embree"):
        s = run(LoadScene, {"path": path})
        sc = s["scene"]
        print(json.dumps({"polygons": len(sc.verts),
                          "triangle_polygons": int(is_triangle(sc.verts).sum())}), flush=True)
        pr = run(ProjectTextures, {}, scene=sc, camera=s["camera"], photo=s["photo"])
        sol = run(RadiositySolve, SETTINGS["RadiositySolve"], scene=sc, projection=pr)["solution"]
        ref = run(TextureRefine, SETTINGS["TextureRefine"], scene=sc, solution=sol, projection=pr)
        print(json.dumps({"links": int(len(ref.recv))}), flush=True)
        un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])["unoccluded"]
        img = run(Relight, {"light_scale": {"lamp": 0.0}}, solution=ref, unoccluded=un,
                  projection=pr, photo=s["photo"], camera=s["camera"])
    if relit_out:
        np.save(relit_out, np.asarray(img.pixels[:, :, :3], np.float32))
        np.save(relit_out.replace(".npy", "_inside.npy"), pr.pix_poly >= 0)


def rss_mb(pid: int) -> float:
    """Resident MB of a process now (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(x.split()[1]) for x in f if x.startswith("VmRSS:")) / 1024
    except (OSError, StopIteration):
        return 0.0


def run_capped(path: str, caps: tuple, relit_out: str | None = None) -> dict:
    """run_one in a fresh process, stopped past caps = (CPU seconds, wall seconds, resident MB).
    {node: {cpu_s, maxrss_mb}, polygons, …, "stopped": why (absent if it finished)}."""
    import resource

    cap_cpu, cap_wall, cap_mb = caps

    def limit():
        resource.setrlimit(resource.RLIMIT_CPU, (int(cap_cpu), int(cap_cpu) + 5))

    cmd = [sys.executable, __file__, "--one", path] + (["--relit", relit_out] if relit_out else [])
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.PIPE, text=True,
                                preexec_fn=limit)
        t0, stopped, peak = time.monotonic(), None, 0.0
        while proc.poll() is None:
            peak = max(peak, rss_mb(proc.pid))
            if peak > cap_mb:
                stopped = f"over {cap_mb:.0f} MB resident"
            elif time.monotonic() - t0 > cap_wall:
                stopped = f"over {cap_wall:.0f} s wall"
            if stopped:
                proc.kill()
                break
            time.sleep(0.2)
        err = proc.communicate()[1]
        out.seek(0)
        row = {"nodes": {}}
        for line in out.read().splitlines():
            d = json.loads(line)
            if "node" in d:
                row["nodes"][d.pop("node")] = d
            else:
                row.update(d)
    if stopped is None and proc.returncode:
        stopped = (f"over {cap_cpu:.0f} s CPU" if proc.returncode == -24
                   else f"failed: {err.strip().splitlines()[-1:]}")
    if stopped:
        at = next((n for n in NODES if n not in row["nodes"]), "the end")
        row["stopped"] = f"{stopped}, in {at}"
    row["peak_mb"] = max([peak] + [d["maxrss_mb"] for d in row["nodes"].values()])
    row["preprocess_s"] = sum(row["nodes"].get(n, {}).get("cpu_s", 0.0) for n in PREPROCESS)
    row["preprocess_wall_s"] = sum(row["nodes"].get(n, {}).get("wall_s", 0.0) for n in PREPROCESS)
    return row


def describe(row: dict) -> str:
    nd = row["nodes"]
    parts = ", ".join(f"{n} {nd[n]['cpu_s']:.1f}" for n in NODES if n in nd)
    state = f"STOPPED ({row['stopped']})" if "stopped" in row else "done"
    return (f"{row['triangles']:6d} triangles → {row.get('polygons', '?')} polygons "
            f"({row.get('triangle_polygons', '?')} triangles): {state}; preprocess "
            f"{row['preprocess_s']:.1f} s CPU, {row['preprocess_wall_s']:.1f} s wall ({parts}), "
            f"{row.get('links', '?')} links, "
            f"peak {row['peak_mb']:.0f} MB; load {os.getloadavg()[0]:.1f}")


def growth(rows: list) -> str:
    """The exponent k of CPU seconds ∝ triangles^k between consecutive finished sizes."""
    done = [r for r in rows if "stopped" not in r]
    return ", ".join(f"{a['triangles']}→{b['triangles']}: "
                     f"{np.log(b['preprocess_s'] / a['preprocess_s']) / np.log(b['triangles'] / a['triangles']):.2f}"
                     for a, b in zip(done, done[1:]))


def plot(rows, path):
    """CPU seconds (preprocess and per node) and peak memory against triangles, log-log; a
    size that was stopped is a red ▲ at what it had used by then (a lower bound)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows if "stopped" not in r]
    cut = [r for r in rows if "stopped" in r]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for node in ("LoadScene",) + PREPROCESS + ("Relight",):
        pts = [(r["triangles"], r["nodes"][node]["cpu_s"]) for r in rows if node in r["nodes"]]
        if pts:
            ax[0].loglog(*zip(*pts), ".--", lw=0.8, label=node)
    for k, key in enumerate(("preprocess_s", "peak_mb")):
        ax[k].loglog([r["triangles"] for r in done], [r[key] for r in done], "ko-",
                     label="preprocess" if k == 0 else "peak resident")
        ax[k].loglog([r["triangles"] for r in cut], [r[key] for r in cut], "r^", ms=8,
                     label="stopped (at least)")
    ax[0].axhline(90, color="grey", lw=0.8)
    ax[1].axhline(4096, color="grey", lw=0.8)
    ax[0].set(xlabel="triangles in the mesh", ylabel="CPU s", title="time (grey: 90 s)")
    ax[1].set(xlabel="triangles in the mesh", ylabel="MB", title="peak memory (grey: 4 GB)")
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def peer(folder: str, relit: np.ndarray, inside: np.ndarray) -> None:
    """Mitsuba's spp and CPU seconds to reach the relit image's PSNR against 1024 spp."""
    import yaml

    from nodes.loscos import mitsuba_ref as MR
    from nodes.loscos.scene import parse_scene

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from loscos_scenes import psnr

    doc = yaml.safe_load(open(os.path.join(folder, "scene.yaml")))
    sc, _, _ = parse_scene(doc, base_dir=folder)
    cam = doc["camera"]

    def render(spp, seed):
        return MR.render_photo(sc, (cam["position"], cam["look_at"], cam["up"]), cam["fov_deg"],
                               cam["width"], cam["height"], spp, seed=seed,
                               emit_scale={"lamp": 0.0})

    ref = render(1024, 23)
    goal = psnr(relit, ref, inside)
    print(f"  peer: relit image (lamp off) vs Mitsuba 1024 spp: {goal:.2f} dB inside the room")
    spp = 1
    while spp <= 1024:
        c = time.process_time()
        q = psnr(render(spp, 5), ref, inside)
        print(f"    Mitsuba {spp:4d} spp: {q:6.2f} dB, {time.process_time() - c:6.2f} s CPU",
              flush=True)
        if q >= goal:
            break
        spp *= 2


def measure(n: int, a) -> dict:
    """One size: its scene written, run capped in a fresh process (and the peer, if asked)."""
    with tempfile.TemporaryDirectory() as d:
        path, tris = write_scene(n, d, a.photo)
        relit = os.path.join(d, "relit.npy") if n == a.peer else None
        row = dict(run_capped(path, (a.cap_cpu, a.cap_wall, a.cap_mb), relit), triangles=tris)
        print(describe(row), flush=True)
        if relit and "stopped" not in row:
            peer(d, np.load(relit), np.load(relit.replace(".npy", "_inside.npy")))
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", type=int, default=[1000, 2000, 5000, 10000, 20000, 50000])
    ap.add_argument("--plot", default=None)
    ap.add_argument("--cap-cpu", type=float, default=600.0, help="CPU seconds per size")
    ap.add_argument("--cap-wall", type=float, default=3600.0, help="wall seconds per size")
    ap.add_argument("--cap-mb", type=float, default=5000.0, help="resident MB per size")
    ap.add_argument("--peer", type=int, default=None, help="the size to run Mitsuba's peer at")
    ap.add_argument("--photo", nargs=3, type=int, default=[64, 48, 16], metavar=("W", "H", "SPP"),
                    help="the photo's size and Mitsuba samples per pixel")
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child: one scene file
    ap.add_argument("--relit", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        run_one(a.one, a.relit)
        return
    rows = sorted((measure(n, a) for n in a.sizes), key=lambda r: r["triangles"])
    print("CPU s ∝ triangles^k:", growth(rows))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    if a.plot:
        os.makedirs(os.path.dirname(os.path.abspath(a.plot)), exist_ok=True)
        plot(rows, a.plot)
        print("wrote", a.plot)


if __name__ == "__main__":
    main()
