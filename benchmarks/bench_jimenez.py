"""Jimenez 2010 nodes (issue 5): LocalHistMatch cost vs radius, SkinShade at 1280×720.

(a) LocalHistMatch on 2048² maps at r = 16 and r = 128 (goal ≤ 30 ms each, equal within
    noise): the whole node (statistics of neutral + target, eq. 3, 256² scale/bias) in its
    ``fast`` (default) and ``exact`` modes, the disc statistics of one map (eq. 1) both ways,
    and the peer: cv2.filter2D with the normalised disc kernel (mean and mean of squares of
    one map, float32), same machine, same process, interleaved.
(b) SkinShade on 1280×720 (LUT lookup, SSS with a depth gradient and with flat depth,
    Kelemen specular), then its parts on the whole image, interleaved: ``lut_lookup`` against
    the peer cv2.remap (INTER_LINEAR, BORDER_REPLICATE: the same bilinear lookup with 1/32-cell
    fixed-point weights, multi-threaded; same float32 map coordinates), the float32 Kelemen
    specular against the same function in float64 (the reference dtype), and sss_blur at
    flat depth.

Median (min) of ``--runs`` timings after one warm-up; the runs of the cases being compared are
interleaved so that a load change on the machine hits all of them alike (the fast node at both
radii; the disc statistics and the peer; the exact path).
Run:  .venv/bin/python benchmarks/bench_jimenez.py
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


def timeit(fns: dict, runs: int) -> dict:
    """{name: (median ms, min ms, median CPU ms)}: one warm-up each, then ``runs`` interleaved
    rounds.  CPU: this process's time on all its threads per call (what a call costs the
    cores; other jobs on a shared machine do not inflate it)."""
    for fn in fns.values():
        fn()  # warm-up (FFT plans, kernel caches)
    ts = {k: [] for k in fns}
    cs = {k: [] for k in fns}
    for _ in range(runs):
        for k, fn in fns.items():
            c, t = time.process_time(), time.perf_counter()
            fn()
            ts[k].append(time.perf_counter() - t)
            cs[k].append(time.process_time() - c)
    return {k: (statistics.median(v) * 1e3, min(v) * 1e3, statistics.median(cs[k]) * 1e3) for k, v in ts.items()}


def fmt(t):
    return f"{t[0]:7.1f} ms ({t[1]:.1f}; CPU {t[2]:.1f})"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--skip-shade", action="store_true")
    ap.add_argument("--skip-histmatch", action="store_true", help="only (b), SkinShade")
    a = ap.parse_args()
    import cv2

    print(f"cores: {os.cpu_count()}, cv2 threads: {cv2.getNumThreads()}")
    if not a.skip_histmatch:
        histmatch(a)
    if not a.skip_shade:
        skinshade(a)


def histmatch(a):
    import cv2

    from graphkit import Image
    from graphkit.contract import compute_checked
    from nodes.jimenez.histmatch import LocalHistMatch, disc_kernel, grid_mean_std, local_mean_std

    rng = np.random.default_rng(0)
    N = a.size
    hn = Image((rng.random((N, N, 1)) * 0.1).astype(np.float32))
    ht = Image((rng.random((N, N, 1)) * 0.2).astype(np.float32))
    one = hn.pixels[..., 0]
    print(f"(a) LocalHistMatch on {N}×{N}, median (min) of {a.runs} runs")
    nodes, stats = {}, {}
    for r in (16.0, 128.0):
        fast = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=256))
        k = disc_kernel(r)
        k32 = (k / k.sum()).astype(np.float32)

        def peer(k32=k32):
            mu = cv2.filter2D(one, -1, k32)
            ex2 = cv2.filter2D(cv2.multiply(one, one), -1, k32)
            return cv2.sqrt(cv2.max(ex2 - mu * mu, 0.0))

        nodes[("node", r)] = lambda fast=fast: compute_checked(fast, neutral=hn, target=ht)
        stats[("stats", r)] = lambda r=r: grid_mean_std([one], r)
        stats[("peer", r)] = peer
    # groups timed apart (interleaved within each): the fast node's timings are not disturbed
    # by the half-second exact runs and peer convolutions between them
    t = {**timeit(nodes, a.runs), **timeit(stats, a.runs)}
    slow = {}
    for r in (16.0, 128.0):  # the exact path is ~20× slower: fewer runs
        exact = LocalHistMatch(LocalHistMatch.Params(radius=r, stats_size=256, mode="exact"))
        slow[("node", r)] = lambda exact=exact: compute_checked(exact, neutral=hn, target=ht)
        slow[("stats", r)] = lambda r=r: local_mean_std(one, r)
    te = timeit(slow, max(3, a.runs // 5))
    for r in (16.0, 128.0):
        print(f"  r={r:5.0f}: node fast {fmt(t[('node', r)])}, exact {fmt(te[('node', r)])}  |  "
              f"disc μ,σ of one map: fast {fmt(t[('stats', r)])}, exact {fmt(te[('stats', r)])}  |  "
              f"peer cv2.filter2D μ,σ {fmt(t[('peer', r)])}  ratio fast/peer {t[('stats', r)][0] / t[('peer', r)][0]:.3f}")
    print(f"  ratio r=128 / r=16 (median): node fast {t[('node', 128.0)][0] / t[('node', 16.0)][0]:.2f}, "
          f"node exact {te[('node', 128.0)][0] / te[('node', 16.0)][0]:.2f}, "
          f"peer cv2.filter2D {t[('peer', 128.0)][0] / t[('peer', 16.0)][0]:.2f}")


def skinshade(a):
    import cv2

    from graphkit import Image, Light
    from graphkit.contract import compute_checked
    from nodes.common.microfacet import kelemen_specular
    from nodes.common import sss
    from nodes.common.sss import sss_blur
    from nodes.jimenez.shade import SkinShade
    from nodes.jimenez.skinlut import CHD_MAX, CM_MAX, SkinColorLUT, lut_corners, lut_lookup

    rng = np.random.default_rng(1)

    lut = SkinColorLUT().compute()["lut"]
    H, W = 720, 1280
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    nrm = Image(np.dstack([(xx - W / 2) / W, (yy - H / 2) / H, -np.ones((H, W), np.float32)]))
    depth = Image((450.0 + 40.0 * ((xx - W / 2) / W) ** 2 + 30.0 * ((yy - H / 2) / H) ** 2)[..., None])
    mel = Image((0.01 + 0.01 * rng.random((H, W, 1))).astype(np.float32))
    hem = Image((0.02 + 0.05 * rng.random((H, W, 1))).astype(np.float32))
    light = Light(direction=(0.4, -0.3, -1.0), ambient=(0.05, 0.05, 0.05))
    print(f"(b) SkinShade on {W}×{H}, median (min; median CPU) of {a.runs} runs, load average "
          f"{os.getloadavg()[0]:.1f}; peer: cv2.GaussianBlur of a {W}×{H} RGB float32 image at the "
          f"largest Gaussian's σ, in the same rounds")
    fns = {}
    maps = dict(melanin=mel, hemoglobin=hem, lut=lut, light=light, normals=nrm)
    rgb = rng.random((H, W, 3), dtype=np.float32)
    for mpp in (0.5, 0.25):
        node = SkinShade(SkinShade.Params(mm_per_pixel=mpp))
        fns[("depth", mpp)] = lambda node=node: compute_checked(node, **maps, depth=depth)
        fns[("flat", mpp)] = lambda node=node: compute_checked(node, **maps)
        fns[("peer", mpp)] = lambda s=np.sqrt(7.41) / mpp: cv2.GaussianBlur(rgb, (0, 0), s)
    t = timeit(fns, a.runs)
    for mpp in (0.5, 0.25):
        pr = t[("peer", mpp)]
        print(f"  {mpp} mm/px (largest Gaussian σ = {np.sqrt(7.41) / mpp:.1f} px): with depth gradient "
              f"{fmt(t[('depth', mpp)])}, flat depth {fmt(t[('flat', mpp)])}, peer {fmt(pr)}; × peer "
              f"(median, CPU): depth {t[('depth', mpp)][0] / pr[0]:.2f}, {t[('depth', mpp)][2] / pr[2]:.2f}; "
              f"flat {t[('flat', mpp)][0] / pr[0]:.2f}, {t[('flat', mpp)][2] / pr[2]:.2f}")
    # a new face every frame: the SSS's per-surface weights made again (sss_blur keeps the last two)
    node = SkinShade(SkinShade.Params(mm_per_pixel=0.5))

    def new_face():
        sss._SCATTERS.clear()
        compute_checked(node, **maps, depth=depth)

    t = timeit({"new": new_face, "same": lambda: compute_checked(node, **maps, depth=depth)}, max(3, a.runs // 2))
    print(f"  0.5 mm/px with depth gradient: a new light on the same face {fmt(t['same'])}, "
          f"a new face (depth) every call {fmt(t['new'])}")

    # the parts, each called once on the whole image (the node calls lookup and specular per
    # 48-row band on all cores; cv2 calls inside them and the peer use cv2's own threads)
    table = lut.pixels
    corners = lut_corners(table)
    m, h = mel.pixels[..., 0], hem.pixels[..., 0]
    nv, nu = table.shape[:2]
    n32 = nrm.pixels / np.linalg.norm(nrm.pixels, axis=-1, keepdims=True)
    n64 = n32.astype(np.float64)
    ldir = np.asarray(light.direction, np.float64)
    ldir /= np.linalg.norm(ldir)
    vdir = np.array([0.0, 0.0, -1.0])
    l32, v32 = ldir.astype(np.float32), vdir.astype(np.float32)
    irr = np.ascontiguousarray(np.broadcast_to(np.float32(0.6), (H, W, 3)))

    def remap_peer():
        mx = cv2.pow(np.clip(m, 0, CM_MAX), 1 / 3) * np.float32((nu - 1) / np.cbrt(CM_MAX))
        my = cv2.pow(np.clip(h, 0, CHD_MAX), 1 / 3) * np.float32((nv - 1) / np.cbrt(CHD_MAX))
        return cv2.remap(table, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    parts = {"lut_lookup": lambda: lut_lookup(table, m, h, corners), "remap": remap_peer,
             "spec32": lambda: kelemen_specular(n32, l32, v32, 0.35, 0.18, 0.028, dtype=np.float32),
             "spec64": lambda: kelemen_specular(n64, ldir, vdir, 0.35, 0.18, 0.028),
             "sss": lambda: sss_blur(irr, 0.25, None)}
    t = timeit(parts, a.runs)
    print(f"  parts: lut_lookup {fmt(t['lut_lookup'])}, peer cv2.remap {fmt(t['remap'])}, ratio "
          f"{t['lut_lookup'][0] / t['remap'][0]:.2f}  |  Kelemen specular float32 {fmt(t['spec32'])}, "
          f"float64 {fmt(t['spec64'])}, ratio {t['spec32'][0] / t['spec64'][0]:.2f}  |  "
          f"sss_blur flat 0.25 mm/px {fmt(t['sss'])}")


if __name__ == "__main__":
    main()
