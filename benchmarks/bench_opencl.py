"""The OpenCL backends (plugins/graphkit-opencl) against the numpy reference (issue 15), in one
run, on the same inputs, in the same process:

* KMStack 1280×720, three layers, binary / feathered / all-soft maps (bench_huang's), over the
  spectral skin and over an RGB skin image — the node's whole compute;
* LocalHistMatch 2048², r = 16 and r = 128, fast mode — the node's whole compute;
* the SSS blur of SkinShade / CosmeticShade at 1280×720 (nodes.common.sss.sss_blur: flat
  0.25 mm/px, with a depth gradient, with a skin mask);
* Relight's per-pixel modulation (the part that runs for every change of the emittances) on
  builtin:cornell2 solved to ≥ 5k leaves (``--relight-eps``; the preprocess runs once).

Each case runs numpy and opencl interleaved, round after round (this 2-core machine is shared
and noisy), with a peer in the same rounds (cv2.remap INTER_NEAREST of a 1280×720×3 image, as
in bench_huang); ms are median / best; "np/cl" is numpy time ÷ opencl time (> 1: opencl is
faster), as median / best.  The device is the one the plugin chooses (GRAPHKIT_OPENCL_DEVICE).

``--graphs`` also runs every graph in graphs/ with --backend opencl and every OpenCL-capable
node pinned, and reports the largest difference from the numpy run per node.

Usage: ``.venv/bin/python benchmarks/bench_opencl.py [--runs N] [--only km,histmatch,sss,relight] [--graphs]``
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_huang import timed  # noqa: E402  (interleaved rounds → median, best)


def peer():
    import cv2

    rng = np.random.default_rng(0)
    src = rng.random((720, 1280, 3), dtype=np.float32)
    mx = rng.integers(0, 1280, (720, 1280)).astype(np.float32)
    my = rng.integers(0, 720, (720, 1280)).astype(np.float32)
    return lambda: cv2.remap(src, mx, my, cv2.INTER_NEAREST)


ROWS = []


def row(case, t, ref="numpy", new="opencl"):
    a, b, p = t[ref], t[new], t["peer"]
    line = (f"{case:34s} {a[0] * 1e3:8.1f} /{a[1] * 1e3:7.1f}  {b[0] * 1e3:8.1f} /{b[1] * 1e3:7.1f}  "
            f"{a[0] / b[0]:5.2f} /{a[1] / b[1]:5.2f}  {p[0] * 1e3:5.2f} /{p[1] * 1e3:5.2f}")
    ROWS.append((case, a, b))
    print(line, flush=True)


def km(runs):
    from bench_huang import COSMETICS, maps

    from graphkit import Image
    from graphkit_opencl.km import KMStackOpenCL
    from nodes.huang.stack import KMStack

    p = KMStack.Params(cosmetics=COSMETICS)
    ref, new = KMStack(p), KMStackOpenCL(p)
    skin = Image(np.full((720, 1280, 3), [0.62, 0.42, 0.33], np.float32))
    pe = peer()
    for name, t in maps().items():
        img = Image(t)
        for bg, kw in (("spectral", {}), ("RGB", {"background": skin})):
            r = timed({"numpy": lambda: ref.compute(thickness=img, **kw),
                       "opencl": lambda: new.compute(thickness=img, **kw), "peer": pe}, runs)
            row(f"KMStack 1280×720 {name} {bg}", r)


def histmatch(runs):
    from graphkit import Image
    from graphkit_opencl.histmatch import LocalHistMatchOpenCL
    from nodes.jimenez.histmatch import LocalHistMatch

    rng = np.random.default_rng(0)
    hn = Image((rng.random((2048, 2048, 1)) * 0.1).astype(np.float32))
    ht = Image((rng.random((2048, 2048, 1)) * 0.2).astype(np.float32))
    pe = peer()
    for r in (16.0, 128.0):
        p = LocalHistMatch.Params(radius=r, stats_size=256)
        ref, new = LocalHistMatch(p), LocalHistMatchOpenCL(p)
        t = timed({"numpy": lambda: ref.compute(neutral=hn, target=ht),
                   "opencl": lambda: new.compute(neutral=hn, target=ht), "peer": pe}, runs)
        row(f"LocalHistMatch 2048² r={r:.0f}", t)


def sss(runs):
    from graphkit_opencl.sss import sss_blur as sss_cl
    from nodes.common.sss import sss_blur

    H, W = 720, 1280
    rng = np.random.default_rng(0)
    irr = rng.random((H, W, 3), dtype=np.float32)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    depth = (450.0 + 40.0 * ((xx - W / 2) / W) ** 2 + 30.0 * ((yy - H / 2) / H) ** 2).astype(np.float64)
    mask = (np.hypot((xx - W / 2) / W, (yy - H / 2) / H) < 0.4).astype(np.float32)
    pe = peer()
    for name, kw in (("flat 0.25 mm/px", {}), ("depth gradient", {"depth": depth}), ("skin mask", {"mask": mask})):
        t = timed({"numpy": lambda: sss_blur(irr, 0.25, **kw), "opencl": lambda: sss_cl(irr, 0.25, **kw),
                   "peer": pe}, max(3, runs // 3))
        row(f"SSS 1280×720 {name}", t)


def relight(runs, eps):
    from graphkit import Context
    from graphkit_opencl.relight import modulate_pixels as relight_cl
    from nodes.loscos.display import modulate_pixels
    from nodes.loscos.radiosity import RadiositySolve, TextureRefine
    from nodes.loscos.relight import Unocclude, new_emittance, relight_plan
    from nodes.loscos.scene import LoadScene
    from nodes.loscos.textures import ProjectTextures

    def run(cls, params=None, **kw):
        return cls(cls.Params(**(params or {})), Context()).compute(**kw)

    t0 = time.perf_counter()
    s = run(LoadScene, {"path": "builtin:cornell2"})
    pr = run(ProjectTextures, {}, scene=s["scene"], camera=s["camera"], photo=s["photo"])
    sol = run(RadiositySolve, {"eps_bf": eps, "eps_bfv": eps / 10, "min_area": 1e-3, "max_level": 6},
              scene=s["scene"], projection=pr)["solution"]
    ref = run(TextureRefine, {"max_level": 7, "min_area": 2.5e-4, "max_rounds": 3},
              scene=s["scene"], solution=sol, projection=pr)
    un = run(Unocclude, {}, solution=ref, projection=pr, photo=s["photo"])["unoccluded"]
    px = relight_plan(ref, un, pr, s["photo"].pixels[:, :, :3])
    L = len(ref.leaves)
    print(f"  (Cornell preprocess {time.perf_counter() - t0:.0f} s: {L} leaves, {len(ref.lights)} lights, "
          f"image {px.photo.shape[1]}×{px.photo.shape[0]}, {len(px.index)} drawn pixels)")
    rng = np.random.default_rng(0)
    es = [new_emittance(ref, dict(zip(ref.lights, rng.uniform(0, 2, len(ref.lights)))), {}) for _ in range(8)]
    a, b = modulate_pixels(px, es[0]), relight_cl(px, es[0])
    print(f"  (max |numpy − opencl| {float(np.abs(a - b).max()):.2g})")
    k = iter(range(1 << 30))
    pe = peer()
    t = timed({"numpy": lambda: modulate_pixels(px, es[next(k) % 8]), "opencl": lambda: relight_cl(px, es[next(k) % 8]),
               "peer": pe}, runs * 4)
    row(f"Relight modulation {L} leaves", t)
    return L


def graphs():
    """Every graph with --backend opencl (pinned on every OpenCL-capable node) vs numpy."""
    import tempfile

    sys.path.insert(0, str(HERE.parent / "tests"))
    from test_opencl_graphs import _opencl_nodes, _run

    from graphkit.graphfile import load_graph
    from graphkit.registry import default_registry

    reg = default_registry()
    print("\ngraphs in graphs/ (full graphs), numpy vs every OpenCL-capable node pinned to opencl:")
    for path in sorted((HERE.parent / "graphs").glob("*.yaml")):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            g = load_graph(path, reg)
            ref, _ = _run(g, Path(d) / "c")
            g2 = load_graph(path, reg)
            nodes = _opencl_nodes(g2)
            for n in nodes:
                g2.nodes[n].backend = "opencl"
            got, _ = _run(g2, Path(d) / "c")
            for n in nodes:
                gn = g2.nodes[n]
                diffs = []
                for port in gn.cls.out_ports:
                    x, y = ref.value(f"{n}.{port}"), got.value(f"{n}.{port}")
                    xa = getattr(x, "pixels", None)
                    if xa is not None:
                        diffs.append(f"{port} {float(np.max(np.abs(xa - y.pixels))):.2g}")
                print(f"  {path.stem:13s} {n:16s} {gn.type:15s} max |Δ|: {', '.join(diffs)}")
            print(f"  {path.stem:13s} ({time.perf_counter() - t0:.0f} s)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--only", default="km,histmatch,sss,relight")
    ap.add_argument("--relight-eps", type=float, default=0.1, help="RadiositySolve eps_bf (0.1: ≥ 5k leaves)")
    ap.add_argument("--graphs", action="store_true")
    a = ap.parse_args(argv)
    from graphkit_opencl.runtime import runtime

    rt = runtime()
    print(f"OpenCL device: {rt.index} {rt.describe()} ({'CPU' if rt.is_cpu else 'not a CPU'}); "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'case':34s} {'numpy ms':>17s}  {'opencl ms':>17s}  {'np/cl':>13s}  {'peer ms':>13s}")
    only = set(a.only.split(","))
    if "km" in only:
        km(a.runs)
    if "histmatch" in only:
        histmatch(a.runs)
    if "sss" in only:
        sss(a.runs)
    if "relight" in only:
        relight(a.runs, a.relight_eps)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    if a.graphs:
        graphs()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
