"""Render (Paris 2003 §5): the numpy reference vs the ``opengl`` backend (plugins/graphkit-moderngl)
at 512², frames per second and the time ratio, on the same machine.

Meshes and configurations as ``bench_render.py``: the astronaut's FaceMesh mesh (852
triangles; the capture head if the mediapipe plugin is missing) and a 24k-triangle
head-shaped mesh; 1 light; 1 light + shadow map (512²); + detail texture; 8 lights + shadows +
detail + exposure 2.  Each opengl frame includes the host set-up, the GL passes (shadow maps,
texture-camera depth, main, composite) and the float32 read-back; the renderer (Mesa llvmpipe
on the CPU here, or a GPU) is printed.  The two outputs are also compared (share of image
values outside RenderGL.tolerance), so a fast but wrong backend shows.

Median of ``--runs`` timings after one warm-up.  Run:  .venv/bin/python benchmarks/bench_render_backends.py
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_render import scenes, timeit  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    from graphkit.node import probe
    from graphkit.registry import default_registry
    from nodes.paris.render import Render

    reg = default_registry()
    if "opengl" not in reg.backend_names("Render"):
        print("Render has no opengl backend: pip install -e plugins/graphkit-moderngl")
        return 1
    GL = reg.backend_class("Render", "opengl")
    why = probe(GL)
    if why:
        print(f"opengl backend unavailable: {why}")
        return 1
    from graphkit_moderngl.runtime import runtime

    print(f"cores: {os.cpu_count()}, frame {a.size}×{a.size}, median of {a.runs} runs, "
          f"OpenGL: {runtime().describe()}")
    tol = {**Render.tolerance, **GL.tolerance}
    for name, mesh, cam, mat, cases in scenes(a.size):
        print(f"\n{name}: {len(mesh.faces)} triangles")
        print(f"  {'configuration':42s} {'numpy fps':>10s} {'opengl fps':>11s} {'speed-up':>9s} {'differing':>10s}")
        for label, params, lights, extra in cases:
            p = Render.Params(eye_highlights="off", **params)
            ref_node, gl_node = Render(p), GL(p)
            run_ref = lambda: ref_node.compute(mesh=mesh, camera=cam, material=mat, lights=lights, **extra)
            run_gl = lambda: gl_node.compute(mesh=mesh, camera=cam, material=mat, lights=lights, **extra)
            tr, tg = timeit(run_ref, a.runs), timeit(run_gl, a.runs)
            x, y = run_ref()["image"].pixels, run_gl()["image"].pixels
            bad = 1 - np.isclose(y, x, rtol=tol["rtol"], atol=tol["atol"]).mean()
            print(f"  {label:42s} {1 / tr:10.2f} {1 / tg:11.2f} {tr / tg:8.1f}× {bad:10.3%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
