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

from bench_render import big_mesh, face_mesh, timeit  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    from graphkit import Image, Light
    from graphkit.node import probe
    from graphkit.registry import default_registry
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import FrameFace, Render

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
    mat = PhongMaterial(diffuse=(0.6, 0.45, 0.3), specular=0.2, shininess=10.0)
    rng = np.random.default_rng(0)
    lights8 = []
    for i in range(8):
        az, el = rng.uniform(-60, 60), rng.uniform(-30, 40)
        a_, e_ = np.radians(az), np.radians(el)
        lights8.append(Light(direction=(np.sin(a_) * np.cos(e_), -np.sin(e_), -np.cos(a_) * np.cos(e_)),
                             intensity=0.25))
    one = [Light(direction=(0.3, -0.3, -0.9))]
    tol = {**Render.tolerance, **GL.tolerance}
    for name, mesh, cam0 in (face_mesh(), big_mesh()):
        cam = FrameFace(FrameFace.Params(size=a.size, margin=0.05)).compute(mesh=mesh, camera=cam0)["camera"]
        detail = Image(rng.uniform(0.8, 1.2, (cam0.height, cam0.width, 3)).astype(np.float32))
        print(f"\n{name}: {len(mesh.faces)} triangles")
        print(f"  {'configuration':42s} {'numpy fps':>10s} {'opengl fps':>11s} {'speed-up':>9s} {'differing':>10s}")
        cases = [
            ("1 light", dict(shadows=False), one, {}),
            ("1 light + shadow map", dict(shadows=True, shadow_map_size=512), one, {}),
            ("1 light + shadows + detail", dict(shadows=True, shadow_map_size=512), one,
             dict(detail=detail, texture_camera=cam0)),
            ("8 lights + shadows + detail + exposure 2", dict(shadows=True, shadow_map_size=512, exposure=2.0),
             lights8, dict(detail=detail, texture_camera=cam0)),
        ]
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
