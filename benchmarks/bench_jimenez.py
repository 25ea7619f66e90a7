"""Jimenez 2010 nodes (issue 5): LocalHistMatch cost vs radius, SkinShade at 1280×720.

(a) LocalHistMatch on 2048² maps at r = 16 and r = 128 (goal ≤ 30 ms each, equal within
    noise): the whole node (statistics of neutral + target, eq. 3, 256² scale/bias), the disc
    statistics of one map (eq. 1), and the peer: cv2.filter2D with the normalised disc kernel
    (mean and mean of squares of one map), same machine, same process.
(b) SkinShade on 1280×720 (LUT lookup, SSS with a depth gradient, Kelemen specular).

Median of ``--runs`` timings after one warm-up.  Run:  .venv/bin/python benchmarks/bench_jimenez.py
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def timeit(fn, runs):
    fn()  # warm-up (FFT plans, kernel spectrum cache)
    ts = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts) * 1e3, min(ts) * 1e3


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", type=int, default=2048)
    a = ap.parse_args()
    import cv2

    from graphkit import Image, Light
    from nodes.jimenez.histmatch import LocalHistMatch, disc_kernel, local_mean_std
    from nodes.jimenez.shade import SkinShade
    from nodes.jimenez.skinlut import SkinColorLUT

    print(f"cores: {os.cpu_count()}, cv2 threads: {cv2.getNumThreads()}")
    rng = np.random.default_rng(0)
    N = a.size
    hn = Image((rng.random((N, N, 1)) * 0.1).astype(np.float32))
    ht = Image((rng.random((N, N, 1)) * 0.2).astype(np.float32))
    one = hn.pixels[..., 0]
    print(f"(a) LocalHistMatch on {N}×{N}, median (min) of {a.runs} runs")
    for r in (16.0, 128.0):
        node = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=256))
        med, mn = timeit(lambda: node.compute(neutral=hn, target=ht), a.runs)
        smed, smn = timeit(lambda: local_mean_std(one, r), a.runs)
        k = disc_kernel(r)
        k /= k.sum()
        k32 = k.astype(np.float32)

        def peer():
            mu = cv2.filter2D(one, -1, k32)
            ex2 = cv2.filter2D(one * one, -1, k32)
            return np.sqrt(np.maximum(ex2 - mu * mu, 0))

        pmed, pmn = timeit(peer, a.runs)
        print(f"  r={r:5.0f}: node {med:7.1f} ms ({mn:.1f})  |  disc μ,σ of one map {smed:7.1f} ms ({smn:.1f})"
              f"  |  peer cv2.filter2D μ,σ {pmed:7.1f} ms ({pmn:.1f})  ratio ours/peer {smed / pmed:.2f}")
    lut = SkinColorLUT().compute()["lut"]
    H, W = 720, 1280
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    nrm = np.dstack([(xx - W / 2) / W, (yy - H / 2) / H, -np.ones((H, W), np.float32)])
    depth = (450.0 + 40.0 * ((xx - W / 2) / W) ** 2 + 30.0 * ((yy - H / 2) / H) ** 2)[..., None]
    mel = Image((0.01 + 0.01 * rng.random((H, W, 1))).astype(np.float32))
    hem = Image((0.02 + 0.05 * rng.random((H, W, 1))).astype(np.float32))
    light = Light(direction=(0.4, -0.3, -1.0), ambient=(0.05, 0.05, 0.05))
    print(f"(b) SkinShade on {W}×{H}, median (min) of {a.runs} runs")
    for mpp in (0.5, 0.25):
        node = SkinShade(SkinShade.Params(mm_per_pixel=mpp))
        med, mn = timeit(lambda: node.compute(melanin=mel, hemoglobin=hem, lut=lut, light=light,
                                              normals=Image(nrm), depth=Image(depth.astype(np.float32))), a.runs)
        flat = timeit(lambda: node.compute(melanin=mel, hemoglobin=hem, lut=lut, light=light,
                                           normals=Image(nrm)), a.runs)
        print(f"  {mpp} mm/px (largest Gaussian σ = {np.sqrt(7.41) / mpp:.1f} px): with depth gradient "
              f"{med:7.1f} ms ({mn:.1f}), flat depth {flat[0]:7.1f} ms ({flat[1]:.1f})")


if __name__ == "__main__":
    main()
