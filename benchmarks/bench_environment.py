"""Relighting to an environment (issue 26 items 4 and 6): accuracy against Mitsuba and the cost
of turning the environment.

1. For every map of nodes/paris/data/make_envmaps.py (TUNE maps chose EnvironmentLights' and
   Render's environment defaults, CHECK maps did not): the relit head's PSNR against Mitsuba's
   render of the same diffuse head under the same ``envmap`` emitter
   (tests/data/envmap_refs.npz), with the SH ambient alone (0 lights) and with 8, 16 (default)
   and 32 lights, and with 16 lights shadowed by a shadow map each (Render's
   ``environment_basis: 0``, as before Render 6); and the energy the lights + ambient hold
   over the map's ∫ L dω.
2. An environment rotation at 1024² after the preprocess is cached: the astronaut photo
   upsampled to 1024², its FaceMesh mesh and camera (the preprocess, done once), then per
   rotation LoadEnvironment (builtin:envmaps/NAME.exr, ``--map``) → EnvironmentLights → Render
   (``--backend`` numpy or opengl — there with ``mouth: skin``, the GL programs' mouth, and
   ``environment_basis: 0``, the GL programs' shadow map per light; 16 lights + SH, those of
   at least environment_shadows × the brightest's luminance shadowed, detail texture) →
   CompositeFace.  On numpy the shadows come from Render's visibility basis, whose directions
   are drawn when a light first needs them: the rotations (15°, 30°, …) are timed on their
   first visit (new directions drawn) and again (``revisit``: every direction drawn, the
   steady state of a turning environment).  With ``--prefill`` the basis is filled first,
   every direction drawn (as the studio does in the background after its first render: the
   interactive session's preprocess, its CPU and wall time reported apart), then the rotations
   are timed at angles never visited (15°, 30°, …; the warm-up was at 0°).  Each map starts
   from a cold Render (its kept geometry cleared: no directions drawn by another map's turns).
   Median CPU seconds (time.process_time: this process, all its threads — with opengl also
   Mesa llvmpipe's, which run in this process) and wall seconds over ``--repeat`` rotations,
   with Render under one light (as face_relight.yaml's portraits, same backend) as the peer.
   The opengl Render is given the engine's input digests (Context.inputs), as in a graph run,
   so it keeps its light-independent set-up between rotations; a first untimed call warms it.

Run:  .venv/bin/python benchmarks/bench_environment.py [--repeat 5] [--size 1024] [--lights 16]
      [--backend numpy|opengl] [--environment-basis N] [--prefill] [--map NAME …] [--skip-psnr]
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


def psnr_table() -> None:
    from nodes.io.environment import read_hdr
    from nodes.paris.data import make_envmaps as E
    from nodes.paris.environment import map_energy

    refs = np.load(E.REFS)
    print("map        set    " + "  ".join(f"{n:>5d} lights" for n in (0, 8, 16, 32))
          + "  16, shadow maps   energy ratio (16)")
    for name in E.TUNE + E.CHECK:
        px = read_hdr(os.path.join(E.HERE, "envmaps", name + ".exr"))
        row = []
        for n in (0, 8, 16, 32):
            img, cov = E.relight(px, lights=n)
            row.append(f"{E.skin_psnr(img, refs[name], cov):8.2f} dB")
        img, cov = E.relight(px, render={"environment_basis": 0}, lights=16)  # Render 5's way: the peer
        row.append(f"{E.skin_psnr(img, refs[name], cov):11.2f} dB   ")
        ratio = E.lighting(px).energy() / map_energy(px)
        print(f"{name:10s} {'tune' if name in E.TUNE else 'check':5s} " + "  ".join(row)
              + "   " + " ".join(f"{r:.6f}" for r in ratio))


def _timed(fn):
    c, w = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c, time.perf_counter() - w


def _renderer(backend: str, basis: int | None = None):
    """A function (inputs → Render's outputs) on ``backend``, checked as the engine does
    (``basis``: Render's environment_basis, its default if None; 0 on opengl)."""
    from graphkit import Context
    from graphkit.contract import check_inputs, compute_checked
    from graphkit.registry import default_registry
    from nodes.paris.render import Render

    if backend == "numpy":
        render = Render(Render.Params() if basis is None else Render.Params(environment_basis=basis))
        return lambda **kw: compute_checked(render, **kw)
    gl = default_registry().backend_class("Render", backend)
    if not gl.available():
        raise SystemExit(f"the {backend} backend is not available here: {gl.why_unavailable()}")

    def run(**kw):
        check_inputs(Render, kw)
        dig = {k: f"bench:{k}" for k in ("mesh", "camera", "detail", "texture_camera")}  # fixed inputs
        # the GL programs do not draw the mouth from the photo's detail (Render's default
        # mouth: photo): the opengl Render shades it as skin
        return gl(Render.Params(mouth="skin", environment_basis=0), Context(inputs=dig)).compute(**kw)
    return run


def _face_basis():
    """The visibility basis of the face Render drew last (the last geometry it kept)."""
    from nodes.paris import render as R

    return next(iter(R._GEOMETRY[next(reversed(R._GEOMETRY))].bases.values()))


def rotation_timing(size: int, repeat: int, lights: int, backend: str = "numpy", envmap: str = "interior",
                    basis: int | None = None, prefill: bool = False) -> None:
    import cv2
    import skimage.data

    from graphkit import Image, Light
    from graphkit.contract import compute_checked
    from graphkit.node import Context
    from graphkit.registry import default_registry
    from nodes.common.color import srgb_to_linear
    from nodes.io.environment import LoadEnvironment
    from nodes.paris.composite import CompositeFace
    from nodes.paris.environment import EnvironmentLights, shadow_map_sizes
    from nodes.paris import render as R
    from nodes.paris.render import Render
    from nodes.paris.mesh import SmoothMesh
    from nodes.paris.models import PhongMaterial

    photo = srgb_to_linear(cv2.resize(skimage.data.astronaut(), (size, size), interpolation=cv2.INTER_CUBIC) / 255.0)
    photo = Image(photo.astype(np.float32))
    fm = default_registry().node_class("FaceMesh")().compute(image=photo)
    mesh = SmoothMesh(SmoothMesh.Params(iterations=2)).compute(mesh=fm["mesh"])
    cam = fm["camera"]
    detail = Image(np.random.default_rng(0).uniform(0.8, 1.2, (size, size, 3)).astype(np.float32))
    mat = PhongMaterial(diffuse=(0.55, 0.4, 0.33), specular=0.05, shininess=8.0)
    render = _renderer(backend, basis)
    R._GEOMETRY.clear()  # each map from a cold Render (no directions drawn for another map's turns)
    common = dict(mesh=mesh, camera=cam, material=mat, detail=detail, texture_camera=cam)

    def turn(deg):
        env = LoadEnvironment(LoadEnvironment.Params(path=f"builtin:envmaps/{envmap}.exr", rotation_deg=deg,
                                                     scale=1.5), Context())
        e = compute_checked(env, camera=cam)
        lighting = compute_checked(EnvironmentLights(EnvironmentLights.Params(lights=lights)),
                                   image=e["image"], frame=e["frame"])
        return lighting

    stages = {"LoadEnvironment+EnvironmentLights": [], "Render (environment)": [], "CompositeFace": [],
              "rotation total": [], "Render (1 light, peer)": []}
    light = Light(direction=(0.3, -0.2, -0.93))
    render(environment=turn(0.0), **common)  # warm-up (GL programs, kept set-up), not timed
    render(lights=[light], **common)

    def rotate(i):
        deg = 15.0 * (i + 1)
        lighting, c1, w1 = _timed(lambda: turn(deg))
        out, c2, w2 = _timed(lambda: render(environment=lighting, **common))
        _, c3, w3 = _timed(lambda: compute_checked(CompositeFace(), photo=photo, relit=out["image"],
                                                   coverage=out["coverage"]))
        moved = Light(direction=(0.3 - 0.02 * i, -0.2, -0.93))  # a new light each time (kept nothing)
        _, c4, w4 = _timed(lambda: render(lights=[moved], **common))
        return lighting, {"LoadEnvironment+EnvironmentLights": (c1, w1), "Render (environment)": (c2, w2),
                          "CompositeFace": (c3, w3), "rotation total": (c1 + c2 + c3, w1 + w2 + w3),
                          "Render (1 light, peer)": (c4, w4)}

    lazy = backend == "numpy" and basis != 0
    filled = None
    if lazy and prefill:  # the interactive session's preprocess: every direction drawn
        drawn, c, w = _timed(_face_basis().fill)
        filled = f"  preprocess: the visibility basis filled ({drawn} directions drawn): CPU {c:.2f} s, wall {w:.2f} s"
    passes = ("rotation",) if not lazy else ("new angle, basis filled",) if prefill else ("first visit", "revisit")
    times = {}
    for name in passes:
        times[name] = [rotate(i) for i in range(repeat)]
    lighting = times[passes[0]][-1][0]
    shadowed = sum(s > 0 for s in shadow_map_sizes(lighting.lights, 1024, 0, Render.Params().environment_shadows))
    print(f"\nenvironment rotation at {size}², {envmap}.exr, {lights} lights ({shadowed} cast shadows), "
          f"Render on {backend}{'' if lazy else ' with a shadow map per light'}, median of {repeat} "
          f"(load: {os.getloadavg()[0]:.1f})")
    if filled:
        print(filled)
    for name in passes:
        print(f" {name}:")
        for k in stages:
            c = statistics.median(t[k][0] for _, t in times[name])
            w = statistics.median(t[k][1] for _, t in times[name])
            print(f"  {k:34s} CPU {1000 * c:8.0f} ms   wall {1000 * w:8.0f} ms")
        ratio = statistics.median(t["rotation total"][0] for _, t in times[name]) / \
            statistics.median(t["Render (1 light, peer)"][0] for _, t in times[name])
        print(f"  rotation total / Render with one light (CPU): {ratio:.2f}")
    if lazy:
        basis = _face_basis()
        print(f"  visibility basis: {int(basis.drawn.sum())} of {len(basis.drawn)} directions drawn")


def main(argv=None) -> int:
    from graphkit.memory import tune_malloc

    tune_malloc()  # as the CLI, the studio and Dask workers do
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--lights", type=int, default=16, help="EnvironmentLights' lights in the rotation timing")
    p.add_argument("--backend", choices=("numpy", "opengl"), default="numpy", help="Render's backend in the rotation timing")
    p.add_argument("--skip-psnr", action="store_true")
    p.add_argument("--environment-basis", type=int, default=None, metavar="N",
                   help="numpy Render's environment_basis (0: a shadow map per light, Render 5's way: the peer)")
    p.add_argument("--prefill", action="store_true",
                   help="fill the visibility basis first (timed apart, the studio's background preprocess), "
                        "then time rotations to angles never visited")
    p.add_argument("--map", nargs="+", default=["interior"], metavar="NAME",
                   help="the rotated map(s), names in nodes/paris/data/envmaps (courtyard: every light casts a shadow)")
    a = p.parse_args(argv)
    if not a.skip_psnr:
        psnr_table()
    for name in a.map:
        rotation_timing(a.size, a.repeat, a.lights, a.backend, name, a.environment_basis, a.prefill)
    return 0


if __name__ == "__main__":
    sys.exit(main())
