"""builtin:room preprocess CPU time with Embree, its accuracy against Mitsuba, and Mitsuba's
path-tracing time to the same PSNR (issue 27 item 3).

    nice .venv/bin/python benchmarks/bench_loscos_speed.py [--scene room] [--peer]
                                                         [--cache /tmp/loscos-scenes]

It runs the preprocess at graphs/room_relight.yaml's settings with ``--backend embree`` ray
casting — ProjectTextures, RadiositySolve, TextureRefine,
Unocclude — and prints each stage's CPU seconds, then the total wall seconds (this process,
time.process_time: on a shared machine the CPU time stands for a quiet machine's wall time), the links, the load
average, and the PSNR of "A off" and "B ×2" against Mitsuba references (512 spp, cached under
--cache; loscos_scenes.py's), inside the room and over the whole image.

``--mesh``: the same scene loaded from its triangle-mesh file (``builtin:<scene>_mesh``).

``--peer``: Mitsuba's path tracer on the "A off" image, at 1, 2, 4, … spp against a 1024-spp
reference (seed 23, cached): the spp and CPU seconds at which it first reaches the relit
image's PSNR against that same reference.  Relighting a preprocessed scene costs one Relight
call (≈ 0.05 s); Mitsuba renders each new lighting from scratch.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import loscos_scenes as LS  # noqa: E402

from nodes.common import rays  # noqa: E402
from nodes.loscos.radiosity import RadiositySolve, TextureRefine  # noqa: E402
from nodes.loscos.relight import Relight, Unocclude  # noqa: E402
from nodes.loscos.scene import LoadScene  # noqa: E402
from nodes.loscos.textures import ProjectTextures  # noqa: E402


def preprocess(name: str, builtin: str):
    """(outputs, {stage: CPU s}, {stage: wall s}) of the Embree preprocess of ``builtin:<builtin>``."""
    t, wall = {}, {}

    def clock(key, cls, params, **kw):
        c, w = time.process_time(), time.perf_counter()
        out = LS.run(cls, params, **kw)
        t[key], wall[key] = time.process_time() - c, time.perf_counter() - w
        return out

    with rays.using("embree"):
        s = LS.run(LoadScene, {"path": f"builtin:{builtin}"})
        pr = clock("ProjectTextures", ProjectTextures, {}, scene=s["scene"], camera=s["camera"],
                   photo=s["photo"])
        sol = clock("RadiositySolve", RadiositySolve, LS.RADIOSITY,
                    scene=s["scene"], projection=pr)["solution"]
        ref = clock("TextureRefine", TextureRefine, LS.REFINE,
                    scene=s["scene"], solution=sol, projection=pr)
        un = clock("Unocclude", Unocclude, {}, solution=ref, projection=pr,
                   photo=s["photo"])["unoccluded"]
    return dict(s, projection=pr, solution=ref, unoccluded=un), t, wall


def relit(p, params):
    return LS.run(Relight, params, solution=p["solution"], unoccluded=p["unoccluded"],
                  projection=p["projection"], photo=p["photo"], camera=p["camera"]).pixels


def peer(name, img, ms, cache, inside):
    """Mitsuba's spp and CPU seconds to reach img's PSNR against a 1024-spp reference."""
    path = os.path.join(cache, f"{name}_A_off_1024_seed23.npy")
    if os.path.exists(path):
        ref = np.load(path)
    else:
        ref = ms.render(ms.relit(name, "A off", 1024), 1024, seed=23)
        np.save(path, ref)
    goal = LS.psnr(img, ref, inside)
    print(f"  peer: relit image vs Mitsuba 1024 spp: {goal:.2f} dB inside the room")
    spp = 1
    while spp <= 1024:
        c = time.process_time()
        got = ms.render(ms.relit(name, "A off", spp), spp, seed=5)
        dt = time.process_time() - c
        q = LS.psnr(got, ref, inside)
        print(f"    Mitsuba {spp:4d} spp: {q:6.2f} dB, {dt:6.2f} s CPU", flush=True)
        if q >= goal:
            return spp, dt
        spp *= 2
    return None, None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="room")
    ap.add_argument("--peer", action="store_true")
    ap.add_argument("--mesh", action="store_true", help="load builtin:<scene>_mesh, the same "
                    "scene from its mesh file (data/make_mesh_scenes.py)")
    ap.add_argument("--cache", default="/tmp/loscos-scenes")
    a = ap.parse_args()
    os.makedirs(a.cache, exist_ok=True)
    ms = LS.make_scenes()
    A, B, _ = LS.cases(a.scene, ms)
    p, t, wall = preprocess(a.scene, a.scene + ("_mesh" if a.mesh else ""))
    total = sum(t.values())
    print(f"{a.scene}{' (mesh file)' if a.mesh else ''} --backend embree: preprocess {total:.1f} s CPU ("
          + ", ".join(f"{k} {v:.1f}" for k, v in t.items())
          + f"), {sum(wall.values()):.1f} s wall; {len(p['solution'].recv)} links; "
          f"load {os.getloadavg()[0]:.1f}", flush=True)
    pr = p["projection"]
    inside = pr.pix_poly >= 0
    for case, prm in (("A off", {"light_scale": {A: 0.0}}), ("B x2", {"light_scale": {B: 2.0}})):
        ref = LS.reference(a.scene, case, ms, a.cache)
        img = relit(p, prm)
        print(f"  {case}: PSNR vs Mitsuba 512 spp {LS.psnr(img, ref, inside):.2f} dB inside, "
              f"{LS.psnr(img, ref):.2f} whole", flush=True)
    if a.peer:
        spp, dt = peer(a.scene, relit(p, {"light_scale": {A: 0.0}}), ms, a.cache, inside)
        print(f"  peer: Mitsuba reaches it at {spp} spp in {dt} s CPU; Relight took one call")


if __name__ == "__main__":
    main()
