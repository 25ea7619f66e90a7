"""Loscos 2000 on builtin:cornell2: preprocess time and relight time after changing emittances.

    .venv/bin/python benchmarks/bench_loscos.py [--eps 0.1]

The paper (§6, Fig. 19): 0.2–0.7 s per update for 3.5k–8k leaves on a 195 MHz workstation,
re-gathering over the links.  Here the solution keeps one radiosity response per light (B is
linear in the emittances), and Relight's plan (relight.relight_plan, once per preprocess)
turns those into per-pixel responses — B/D interpolated per vertex, emitter rims by coverage —
so an update is display.modulate_pixels: per pixel a (lights × 3) weighted sum; the
iterative gather/push-pull update of §5 is timed too, for comparison.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from graphkit import Context
from nodes.loscos import hierarchy as HR
from nodes.loscos.radiosity import RadiositySolve, TextureRefine
from nodes.loscos.display import modulate_pixels
from nodes.loscos.relight import Unocclude, new_emittance, relight_plan
from nodes.loscos.scene import LoadScene
from nodes.loscos.textures import ProjectTextures


def run(cls, params=None, **kw):
    return cls(cls.Params(**(params or {})), Context()).compute(**kw)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--eps", type=float, default=0.1, help="eps_bf of RadiositySolve")
    ap.add_argument("--repeat", type=int, default=200)
    a = ap.parse_args()
    t = {}
    t0 = time.perf_counter()
    s = run(LoadScene, {"path": "builtin:cornell2"})
    pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
    t["load+project"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = run(RadiositySolve, {"eps_bf": a.eps, "eps_bfv": a.eps / 10, "min_area": 1e-3,
                               "max_level": 6}, scene=s["scene"], projection=pr)["solution"]
    t["RadiositySolve"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = run(TextureRefine, {"max_level": 7, "min_area": 2.5e-4, "max_rounds": 3},
              scene=s["scene"], solution=sol, projection=pr)
    t["TextureRefine"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])["unoccluded"]
    t["Unocclude"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    prep = relight_plan(ref, un, pr, s["photo"].pixels[:, :, :3])
    t_plan = time.perf_counter() - t0
    L = len(ref.leaves)
    rng = np.random.default_rng(0)
    scales = rng.uniform(0, 2, (a.repeat, len(ref.lights)))
    modulate_pixels(prep, ref.emit)  # warm-up
    dts = []
    for k in range(a.repeat):
        t0 = time.perf_counter()
        e = new_emittance(ref, dict(zip(ref.lights, scales[k])), {})
        img = modulate_pixels(prep, e)
        dts.append(time.perf_counter() - t0)
    dts = np.array(dts)
    # §5 as in the paper: gather + push-pull until stable, on the kept links
    ops = HR.operators(ref.hierarchy())
    E = np.einsum("lsc,sc->lc", ref.resp - ref.rho[:, None, :] * ref.resp_H, ref.emit * 0.5)
    t0 = time.perf_counter()
    B, it = HR.solve(ops, E, ref.rho, tol=1e-4)
    dt_iter = time.perf_counter() - t0
    print(f"leaves {L}, links {len(ref.recv)}, lights {len(ref.lights)}, image {img.shape[1]}×{img.shape[0]}")
    for k, v in t.items():
        print(f"  {k:20s} {v:7.2f} s")
    print(f"  preprocess total     {sum(t.values()):7.2f} s")
    print(f"Relight plan (once per preprocess): {t_plan * 1e3:.0f} ms")
    print(f"relight after changing emittances ({a.repeat} runs): median "
          f"{np.median(dts) * 1e3:.2f} ms, best {dts.min() * 1e3:.2f} ms (goal ≤ 20 ms)")
    print(f"relight by gather/push-pull iterations (§5, tol 1e-4, {it} iterations): {dt_iter * 1e3:.1f} ms"
          f" ({dt_iter / np.median(dts):.0f}× the response update)")


if __name__ == "__main__":
    main()
