"""How far ``ballfind._Outline.polish`` carries a circle to the mirror ball's outline, and how
honest the finder's noise level is, on varied_probes' probes (issue 26 item 7).

    .venv/bin/python benchmarks/bench_paris_outline_polish.py tv00x3,tv08x3,tv25x3 [--cache DIR] [--starts 8]

Names are varied_probes' (``tv``/``cv``/``hv`` + number, ``xK`` for K× the size).  Per probe:
(1) the pixel noise of the image stabilised with ``noise_curve``'s lower envelope (the finder's)
and with its isotonic fit, measured on the stabilised image itself (1.4826 × MAD of 2×2 second
differences; 1.0 is honest); (2) the polish started from the true circle: where it stops (the
local maximum there); (3) the polish started from the true circle moved 2 px each of ``--starts``
ways (radius ±1 px in turn): where each lands (centre distance from the truth, px), and how many
land over 1 px from (2) with a higher score — a stronger outline beside the rim, which no search
from there undoes; (4) the CPU per polish.

Seen at stop 38 (tune half, 3×: tv00 tv01 tv03 tv05 tv07 tv08 tv10 tv11 tv12 tv25 tv33 tv42): from
2 px off the polish lands within 0.35 px of the true circle on 7 of the 12, within 0.55–0.78 px on
two (tv07, tv12: 187–194-px balls), and on a stronger outline beside the rim on three (tv05 from
half its starts, 2.8–3.6 px off; tv25, the edge of the ball's cast shadow along one side, 2.4 px;
tv33, 1.4–1.5 px, where the truth is no local maximum) — which is why ProbeLight bounds a polished
outline's direction by its residual, and ballfind refuses a polished rim darker than a mirror's.
The envelope's noise: up to 7 × too low (tv42x3 7.1, tv03x3 5.8; 1.0–1.1 with the isotonic fit).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _pixel_sigma(g) -> float:
    d = (g[1:, 1:] - g[1:, :-1] - g[:-1, 1:] + g[:-1, :-1]) / 2.0
    return float(1.4826 * np.median(np.abs(d)))


def main(argv=None):
    from bench_paris_probes import probe_image
    from bench_paris_rim_coherence import _spec

    from nodes.paris import ballfind as bf
    from nodes.paris.data.make_probes import truth

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", help="comma-separated varied probe names, e.g. tv00x3,tv08x3")
    ap.add_argument("--cache", default=None, help="keep the renders here (as bench_paris_probes.py)")
    ap.add_argument("--starts", type=int, default=8, help="starts 2 px off the true circle, evenly round it")
    a = ap.parse_args(argv)
    print("| probe | r (px) | noise σ, envelope / isotonic | polish from the truth: landed (px) | polish from 2 px "
          "off: landed (px from the truth) | landings > 1 px from it scoring over it | CPU per polish (s) |\n"
          "|---|---|---|---|---|---|---|")
    for name in a.names.split(","):
        spec = _spec(name)
        img = probe_image(spec, a.cache)
        t = truth(spec)
        tc = np.array([t["centre_x"], t["centre_y"], t["radius"]])
        lum = bf.luminance(img)
        g = bf.stabilise(lum)
        s_env, s_iso = _pixel_sigma(g), _pixel_sigma(bf.stabilise(lum, isotonic=True))
        ob = bf._Outline(g, spec.fov_deg)
        home = np.array(ob.polish(tc))          # the local maximum at the true circle
        s_home = ob.score(home)
        landed, higher = [], 0
        t0 = time.process_time()
        for k in range(a.starts):
            ang = 2 * np.pi * k / a.starts
            p = np.array(ob.polish(tc + [2 * np.cos(ang), 2 * np.sin(ang), (-1) ** k]))
            landed.append(float(np.hypot(*(p - tc)[:2])))
            higher += np.hypot(*(p - home)[:2]) > 1.0 and ob.score(p) > s_home + 1e-9
        cpu = (time.process_time() - t0) / a.starts
        print(f"| {name} | {tc[2]:.1f} | {s_env:.2f} / {s_iso:.2f} | {np.hypot(*(home - tc)[:2]):.2f} | "
              f"{' '.join(f'{d:.2f}' for d in landed)} | "
              f"{higher}/{a.starts} | {cpu:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    sys.exit(main())
