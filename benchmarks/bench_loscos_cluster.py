"""RadiositySolve and TextureRefine on furnished mesh rooms of N triangles, with cluster links
(issue 27 item 3; nodes/loscos/clusters.py): CPU seconds and peak memory against N, and the
relit image's PSNR against Mitsuba with and without clustering.

    nice .venv/bin/python benchmarks/bench_loscos_cluster.py [--sizes 2000 5000 10000 20000]
                                                           [--psnr 2000] [--no-cluster]
                                                           [--plot out/loscos_cluster.png]

Each size is bench_loscos_mesh.py's room (its ``room_parts`` and ``write_scene``: OBJ + scene
YAML + Mitsuba photo), run in a fresh process at bench_loscos_mesh's settings with
``--backend embree``: ProjectTextures at ``--resolution`` texels per polygon side (its
per-polygon texel memory is another change's), RadiositySolve, TextureRefine.  Printed per
stage: CPU seconds (time.process_time) and the process's peak RSS after it (ru_maxrss), the
links (polygon links and cluster links), and the load average.  ``--no-cluster`` starts the
links from every pair of polygons (radiosity.CLUSTER_ABOVE set past the scene).

``--psnr N``: the room of N triangles photographed at 160×120 (64 spp), preprocessed with and
without clustering, relit with the lamp off, against Mitsuba's render of the room with the
lamp off (256 spp, 160×120), inside the room (the pixels that see a polygon).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import loscos_scenes as LS  # noqa: E402
from bench_loscos_mesh import SETTINGS, plot, write_scene  # noqa: E402

from nodes.loscos.radiosity import CLUSTER_ABOVE  # noqa: E402

run = LS.run


def preprocess(path: str, resolution: int, cluster: bool):
    """(scene outputs, projection, refined solution, {stage: (CPU s, peak MB)})."""
    from nodes.common import rays
    from nodes.loscos import radiosity as R
    from nodes.loscos.scene import LoadScene
    from nodes.loscos.textures import ProjectTextures

    R.CLUSTER_ABOVE = CLUSTER_ABOVE if cluster else 1 << 60
    stages = {}

    def clock(key, cls, params, **kw):
        c = time.process_time()
        out = run(cls, params, **kw)
        stages[key] = (time.process_time() - c,
                       resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
        return out

    with rays.using("embree"):
        s = run(LoadScene, {"path": path})
        pr = clock("ProjectTextures", ProjectTextures, {"resolution": resolution},
                   scene=s["scene"], camera=s["camera"], photo=s["photo"])
        sol = clock("RadiositySolve", R.RadiositySolve, SETTINGS["RadiositySolve"],
                    scene=s["scene"], projection=pr)["solution"]
        ref = clock("TextureRefine", R.TextureRefine, SETTINGS["TextureRefine"],
                    scene=s["scene"], solution=sol, projection=pr)
    return s, pr, ref, stages


def one(path: str, resolution: int, cluster: bool) -> dict:
    s, _, ref, stages = preprocess(path, resolution, cluster)
    return {"polygons": len(s["scene"].verts), "links": int(len(ref.recv)),
            "cluster_links": 0 if ref.cl_V is None else int(len(ref.cl_V)),
            "cluster_entries": 0 if ref.cl_V is None else int(len(ref.cl_rw) + len(ref.cl_sw)),
            "stages": stages}


def photo_at(folder: str, width: int, height: int, spp: int, lamp: float = 1.0):
    """Re-render the scene's photo at width × height (spp), the lamp's emittance × lamp."""
    import yaml

    from nodes.loscos import mitsuba_ref as MR
    from nodes.loscos.scene import parse_scene

    doc = yaml.safe_load(open(os.path.join(folder, "scene.yaml")))
    cam = dict(doc["camera"], width=width, height=height)
    doc["camera"] = cam
    sc, _, _ = parse_scene(doc, base_dir=folder)
    if lamp != 1.0:
        sc.emittance[[k for k, n in enumerate(sc.light) if n == "lamp"]] *= lamp
    img = MR.render_photo(sc, (cam["position"], cam["look_at"], cam["up"]), cam["fov_deg"],
                          width, height, spp, seed=7 if lamp != 1.0 else 3)
    return doc, np.asarray(img, np.float64)


def psnr_case(n: int, resolution: int):
    """The lamp-off relit image's PSNR against Mitsuba, with and without clustering."""
    import yaml

    from nodes.io.images import encode_image
    from nodes.loscos.relight import Relight, Unocclude

    with tempfile.TemporaryDirectory() as d:
        path, tris = write_scene(n, d)
        doc, photo = photo_at(d, 160, 120, 64)
        with open(os.path.join(d, "photo.exr"), "wb") as f:
            f.write(encode_image(photo.astype(np.float32), ".exr", 16))
        yaml.safe_dump(doc, open(path, "w"))
        _, ref = photo_at(d, 160, 120, 256, lamp=0.0)
        for cluster in (False, True):
            c = time.process_time()
            s, pr, sol, st = preprocess(path, resolution, cluster)
            un = run(Unocclude, {}, solution=sol, projection=pr, photo=s["photo"])["unoccluded"]
            img = run(Relight, {"light_scale": {"lamp": 0.0}}, solution=sol, unoccluded=un,
                      projection=pr, photo=s["photo"], camera=s["camera"]).pixels
            inside = pr.pix_poly >= 0
            print(f"{tris} triangles, {'clustered' if cluster else 'every polygon pair'}: "
                  f"lamp off vs Mitsuba 256 spp {LS.psnr(img, ref, inside):.2f} dB inside, "
                  f"{LS.psnr(img, ref):.2f} whole; RadiositySolve {st['RadiositySolve'][0]:.1f} s "
                  f"CPU, preprocess {time.process_time() - c:.1f} s CPU", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", type=int, default=[2000, 5000, 10000, 20000])
    ap.add_argument("--resolution", type=int, default=16)
    ap.add_argument("--no-cluster", action="store_true")
    ap.add_argument("--psnr", type=int, default=None)
    ap.add_argument("--plot", default=None, help="PNG: RadiositySolve + TextureRefine CPU s "
                    "and peak memory against the triangles")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child: one scene file
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.resolution, not a.no_cluster)))
        return
    if a.psnr:
        psnr_case(a.psnr, a.resolution)
        return
    rows = []
    for n in a.sizes:
        with tempfile.TemporaryDirectory() as d:
            path, tris = write_scene(n, d)
            cmd = [sys.executable, __file__, "--one", path, "--resolution", str(a.resolution)]
            r = subprocess.run(cmd + (["--no-cluster"] if a.no_cluster else []),
                               capture_output=True, text=True)
        if r.returncode:
            print(f"{tris} triangles: failed ({r.stderr.strip().splitlines()[-3:]})")
            continue
        row = json.loads(r.stdout.strip().splitlines()[-1])
        st = row["stages"]
        print(f"{tris:6d} triangles → {row['polygons']} polygons: "
              + ", ".join(f"{k} {c:.1f} s CPU (peak {m:.0f} MB)" for k, (c, m) in st.items())
              + f"; {row['links']} links, {row['cluster_links']} cluster links "
              f"({row['cluster_entries']} member entries); load {os.getloadavg()[0]:.1f}",
              flush=True)
        rows.append({"triangles": tris, "maxrss_mb": st["TextureRefine"][1],
                     "preprocess_s": st["RadiositySolve"][0] + st["TextureRefine"][0]})
    if a.plot and rows:
        plot(rows, a.plot)
        print("wrote", a.plot)


if __name__ == "__main__":
    main()
