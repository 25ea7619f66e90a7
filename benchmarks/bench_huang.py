"""KMStack (Huang 2013 §3.1) at 1280×720 with three layers: numpy reference timings.

Goal from the issue: ≤ 10 ms per frame (the paper renders the whole frame at 170 fps on a 2009
GPU).  Three cosmetic maps, layers foundation_light / blush_rose / lipstick_red over the
spectral CIE TCS13 skin (and over an RGB skin image):

* ``binary``   — regions are hard masks × a thickness: every pixel is on a table node (exact);
* ``feathered`` — face-like ellipses with ~8 px soft edges (the usual FaceMesh-style map);
* ``all-soft`` — every layer's thickness varies at every pixel (worst case: 8-corner interpolation everywhere).

"cold" includes building the spectral thickness table (first frame for a material set);
"warm" reuses it (the per-frame cost).  Median of ``--runs`` runs after warm-up; the whole
node ``compute`` including input checks, as the engine calls it.
Usage: ``.venv/bin/python benchmarks/bench_huang.py [--runs N]``
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

W, H = 1280, 720
COSMETICS = ["foundation_light", "blush_rose", "lipstick_red"]


def maps() -> dict[str, np.ndarray]:
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)

    def ellipse(cx, cy, rx, ry, feather):
        d = np.sqrt(((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2)
        if feather == 0:
            return (d <= 1).astype(np.float32)
        return np.clip((1 - d) * min(rx, ry) / feather + 0.5, 0, 1).astype(np.float32)

    out = {}
    for name, fe in (("binary", 0), ("feathered", 8)):
        face = ellipse(640, 360, 220, 300, fe)
        cheeks = np.maximum(ellipse(540, 400, 60, 40, fe), ellipse(740, 400, 60, 40, fe))
        lips = ellipse(640, 560, 70, 25, fe)
        out[name] = np.stack([0.03 * face, 0.03 * cheeks, 0.05 * lips], -1).astype(np.float32)
    out["all-soft"] = np.stack([0.03 * xx / W, 0.03 * yy / H, 0.05 * (xx * yy) / (W * H)], -1).astype(np.float32)
    return out


def median_seconds(fn, runs: int, warmup: int = 1) -> tuple[float, float]:
    """Median wall time and median CPU time of this process (the CPU time is less sensitive
    to other work on a shared machine; numpy here is single-threaded)."""
    for _ in range(warmup):
        fn()
    ts, cs = [], []
    for _ in range(runs):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return statistics.median(ts), statistics.median(cs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args(argv)
    from graphkit import Image
    from nodes.huang import km
    from nodes.huang.stack import KMStack

    node = KMStack(KMStack.Params(cosmetics=COSMETICS))
    skin = Image(np.full((H, W, 3), [0.62, 0.42, 0.33], np.float32))
    print(f"KMStack {W}×{H}, 3 layers, numpy reference; {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, numpy {np.__version__}")
    print(f"load average {os.getloadavg()[0]:.1f}; wall ms (CPU ms)")
    print(f"{'map':10s} {'background':14s} {'interp px':>10s} {'cold':>16s} {'warm':>16s}")
    for name, t in maps().items():
        timg = Image(t)
        frac = float(np.mean(np.any((t > 0) & (np.abs(t - t.max(axis=(0, 1))) > 0), axis=-1)))
        for bgname, kw in (("spectral TCS13", {}), ("RGB image", {"background": skin})):
            def cold():
                km._TABLES.clear()
                node.compute(thickness=timg, **kw)

            c = median_seconds(cold, max(3, args.runs // 3))
            w = median_seconds(lambda: node.compute(thickness=timg, **kw), args.runs)
            print(f"{name:10s} {bgname:14s} {frac:10.1%} {c[0] * 1e3:8.1f} ({c[1] * 1e3:5.1f}) "
                  f"{w[0] * 1e3:8.1f} ({w[1] * 1e3:5.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
