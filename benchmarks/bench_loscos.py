"""Loscos 2000 on builtin:cornell2: preprocess time and relight time after changing emittances.

    .venv/bin/python benchmarks/bench_loscos.py [--eps 0.1]

The paper (§6, Fig. 19): 0.2–0.7 s per update for 3.5k–8k leaves on a 195 MHz workstation,
re-gathering over the links.  Here the solution keeps one radiosity response per light (B is
linear in the emittances), so an update is a (leaves × lights) weighted sum plus a per-pixel
gather; the iterative gather/push-pull update of §5 is timed too, for comparison.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from graphkit import Context
from nodes.loscos import hierarchy as HR
from nodes.loscos.radiosity import RadiositySolve, TextureRefine
from nodes.loscos.relight import Unocclude, new_emittance, prepare, relight_fast
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
                               "max_level": 6}, scene=s["scene"], projection=pr)
    t["RadiositySolve"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = run(TextureRefine, {"max_level": 7, "min_area": 2.5e-4, "max_rounds": 3},
              scene=s["scene"], solution=sol, projection=pr)
    t["TextureRefine"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])["unoccluded"]
    prep = prepare(ref, un, pr, s["photo"].pixels[:, :, :3])
    t["Unocclude+prepare"] = time.perf_counter() - t0
    L = len(ref.leaves)
    rng = np.random.default_rng(0)
    scales = rng.uniform(0, 2, (a.repeat, len(ref.lights)))
    relight_fast(prep, ref.emit)  # warm-up
    t0 = time.perf_counter()
    for k in range(a.repeat):
        e = new_emittance(ref, dict(zip(ref.lights, scales[k])), {})
        img = relight_fast(prep, e)
    dt = (time.perf_counter() - t0) / a.repeat
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
    print(f"relight after changing emittances (responses, {a.repeat} runs): {dt * 1e3:.2f} ms")
    print(f"relight by gather/push-pull iterations (§5, tol 1e-4, {it} iterations): {dt_iter * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
