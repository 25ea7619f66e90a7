"""Loscos 2000 preprocess with Embree ray casting against the numpy reference, in one run.

    nice .venv/bin/python benchmarks/bench_loscos_embree.py [--scenes room cornell2 cornell3]
                         [--backends embree numpy] [--profile] [--mitsuba]

For each scene it runs the pipeline at the graph's settings (graphs/room_relight.yaml, as
benchmarks/loscos_scenes.py) once per ray-casting backend (nodes/common/rays.py): ProjectTextures,
RadiositySolve, TextureRefine, Unocclude, then Relight for "A off", "B ×2" and a virtual
light.  It prints each stage's wall and CPU seconds per backend with the CPU ratio (on a
shared machine CPU seconds stand for a quiet machine's wall time), the solution's size, and the
PSNR between the backends' relit images (inside the room / whole image; sRGB in [0, 1]), and
with ``--mitsuba`` each backend's PSNR against the Mitsuba references (loscos_scenes.py's,
cached under /tmp/loscos-scenes).  ``--profile`` prints cProfile's top functions of the first
backend's preprocess (by own time and by cumulative time).
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import loscos_scenes as LS  # noqa: E402

from nodes.common import rays  # noqa: E402
from nodes.loscos.radiosity import RadiositySolve, TextureRefine  # noqa: E402
from nodes.loscos.relight import Relight, Unocclude  # noqa: E402
from nodes.loscos.scene import LoadScene  # noqa: E402
from nodes.loscos.textures import ProjectTextures  # noqa: E402

STAGES = ("ProjectTextures", "RadiositySolve", "TextureRefine", "Unocclude")


class Clock:
    """Wall and CPU seconds (this process, all threads) of each stage: on a shared machine the
    CPU seconds are what a quiet one would take as wall time, for single-threaded numpy."""

    def __init__(self):
        self.t = {}

    def __call__(self, key, fn, *a, **kw):
        w, c = time.perf_counter(), time.process_time()
        out = fn(*a, **kw)
        self.t[key] = (time.perf_counter() - w, time.process_time() - c)
        return out


def preprocess(name, clock):
    s = LS.run(LoadScene, {"path": f"builtin:{name}"})
    pr = clock("ProjectTextures", LS.run, ProjectTextures, {}, scene=s["scene"],
               camera=s["camera"], photo=s["photo"])
    sol = clock("RadiositySolve", LS.run, RadiositySolve, LS.RADIOSITY, scene=s["scene"],
                projection=pr)["solution"]
    ref = clock("TextureRefine", LS.run, TextureRefine, LS.REFINE, scene=s["scene"],
                solution=sol, projection=pr)
    un = clock("Unocclude", LS.run, Unocclude, {}, solution=ref, projection=pr,
               photo=s["photo"])["unoccluded"]
    clock.t["preprocess"] = tuple(sum(clock.t[k][i] for k in STAGES) for i in (0, 1))
    return dict(s, projection=pr, solution=ref, unoccluded=un)


def relit(p, name, ms, clock):
    A, B, V = LS.cases(name, ms)
    out = {}
    for case, prm in (("A off", {"light_scale": {A: 0.0}}), ("B x2", {"light_scale": {B: 2.0}}),
                      ("virtual", {"virtual_lights": [V], "eps_bf": 0.3, "eps_bfv": 0.03})):
        out[case] = clock(f"Relight {case}", LS.run, Relight, prm, solution=p["solution"],
                          unoccluded=p["unoccluded"], projection=p["projection"],
                          photo=p["photo"], camera=p["camera"]).pixels
    return out


def inside_mask(pr):
    inside = (pr.pix_poly >= 0).reshape(-1)
    inside[pr.sub_pix[(pr.sub_poly >= 0).any(1)]] = True
    return inside.reshape(pr.pix_poly.shape)


def profile_top(prof, n=14):
    for key in ("tottime", "cumulative"):
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats(key).print_stats(n)
        lines = s.getvalue().splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("ncalls"))
        print(f"  cProfile, sorted by {key}:")
        print("\n".join("    " + ln for ln in lines[start:start + n + 1]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=["room", "cornell2", "cornell3"])
    ap.add_argument("--backends", nargs="+", default=["embree", "numpy"], choices=rays.BACKENDS)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--mitsuba", action="store_true", help="PSNR against the Mitsuba references")
    ap.add_argument("--cache", default="/tmp/loscos-scenes")
    a = ap.parse_args()
    ms = LS.make_scenes()
    print(f"load average {os.getloadavg()[0]:.1f}, {os.cpu_count()} cores")
    for name in a.scenes:
        res = {}
        for k, b in enumerate(a.backends):
            prof = cProfile.Profile() if a.profile and k == 0 else None
            clock = Clock()
            with rays.using(b):
                if prof:
                    prof.enable()
                p = preprocess(name, clock)
                if prof:
                    prof.disable()
                imgs = relit(p, name, ms, clock)
            res[b] = (p, clock.t, imgs)
            sol = p["solution"]
            w, c = clock.t["preprocess"]
            print(f"{name} [{b}]: preprocess {w:.1f} s wall, {c:.1f} s CPU, {len(sol.leaves)} "
                  f"leaves, {len(sol.recv)} links (load {os.getloadavg()[0]:.1f})", flush=True)
            if prof:
                profile_top(prof)
        keys = list(next(iter(res.values()))[1])
        print(f"\n{name}: seconds, wall / CPU  " + "  ".join(f"{b:>15s}" for b in a.backends)
              + ("   ratio (CPU)" if len(a.backends) == 2 else ""))
        for key in keys:
            v = [res[b][1][key] for b in a.backends]
            print(f"  {key:18s}" + "".join(f"{x[0]:9.2f} /{x[1]:7.2f}" for x in v)
                  + (f"  {v[1][1] / max(v[0][1], 1e-9):6.1f}×" if len(v) == 2 else ""))
        inside = inside_mask(res[a.backends[0]][0]["projection"])
        if len(a.backends) == 2:
            b0, b1 = a.backends
            for case in res[b0][2]:
                x, y = res[b0][2][case], res[b1][2][case]
                print(f"  {case:8s} PSNR {b0} vs {b1}: inside {LS.psnr(x, y, inside):.1f} dB, "
                      f"whole {LS.psnr(x, y):.1f} dB")
        if a.mitsuba:
            os.makedirs(a.cache, exist_ok=True)
            for case in res[a.backends[0]][2]:
                ref = LS.reference(name, case, ms, a.cache)
                print(f"  {case:8s} PSNR against Mitsuba (inside / whole): " + ", ".join(
                    f"{b} {LS.psnr(res[b][2][case], ref, inside):.1f} / "
                    f"{LS.psnr(res[b][2][case], ref):.1f} dB" for b in a.backends))
        print(flush=True)


if __name__ == "__main__":
    main()
