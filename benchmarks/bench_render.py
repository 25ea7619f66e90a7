"""Render (Paris 2003 §5) numpy reference backend: frames per second at 512².

Meshes: the astronaut's FaceMesh mesh (852 triangles; the head of the Mitsuba sample capture if
the mediapipe plugin is not installed) and a 24k-triangle head-shaped mesh (the paper's
"scanner" mesh had 24,060 triangles).  Configurations: 1 light; 1 light + shadow map (512²);
1 light + shadows + detail texture; 8 lights + shadows + detail + over-exposure (the paper's
"8L").  Peer on the same machine: moderngl (OpenGL, Mesa llvmpipe on the CPU when no GPU)
drawing the same mesh with per-pixel Phong and a depth test at 512², read back to numpy.

Median of ``--runs`` timings after one warm-up.  Run:  .venv/bin/python benchmarks/bench_render.py
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
    fn()
    ts = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def face_mesh():
    from graphkit import Image
    from graphkit.registry import default_registry

    reg = default_registry()
    if "FaceMesh" in reg.node_names():
        import skimage.data

        from nodes.common.color import srgb_to_linear

        img = Image(srgb_to_linear(skimage.data.astronaut() / 255.0))
        out = reg.node_class("FaceMesh")().compute(image=img)
        return "astronaut FaceMesh", out["mesh"], out["camera"]
    from nodes.paris.data import make_capture as mc

    m, _, _ = mc.head_mesh(4)
    return "capture head (level 4)", m, mc.camera(512)


def big_mesh(n_target=24060):
    import trimesh

    from nodes.paris.data import make_capture as mc

    n = int(round(np.sqrt(n_target / 4)))
    m = trimesh.creation.uv_sphere(radius=1.0, count=[n, n])
    m.vertices *= [72.0, 98.0, 88.0]
    m.vertices[:, 2] += mc.DISTANCE_MM
    return "head-shaped uv sphere", m, mc.camera(512)


def peer_moderngl(mesh, cam, runs):
    try:
        import moderngl
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as e:  # noqa: BLE001
        return None, f"moderngl unavailable: {e}"
    W, H = cam.width, cam.height
    from peers import phong_peer

    vs, fs = phong_peer("330")
    prog = ctx.program(vertex_shader=vs, fragment_shader=fs)
    n, f = 0.1, 10000.0
    # OpenCV intrinsics → clip space (y down in the image)
    P = np.array([[2 * cam.fx / W, 0, 1 - 2 * cam.cx / W, 0],
                  [0, -2 * cam.fy / H, 2 * cam.cy / H - 1, 0],
                  [0, 0, (f + n) / (f - n), -2 * f * n / (f - n)],
                  [0, 0, 1, 0]], np.float32)
    prog["P"].write(P.T.copy().tobytes())
    prog["L"].value = (0.3, -0.3, -0.9)
    prog["kd"].value = (0.6, 0.45, 0.3)
    prog["ks"].value = 0.2
    prog["s"].value = 10.0
    V = (np.asarray(mesh.vertices) @ cam.pose[:3, :3].T + cam.pose[:3, 3]).astype(np.float32)
    N = np.asarray(mesh.vertex_normals, np.float32)
    vbo = ctx.buffer(np.hstack([V, N]).astype(np.float32).tobytes())
    ibo = ctx.buffer(np.asarray(mesh.faces, np.int32).tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "pos", "nrm")], ibo)
    fbo = ctx.simple_framebuffer((W, H), components=4, dtype="f4")

    def frame():
        fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        fbo.clear(0, 0, 0, 1, depth=1.0)
        vao.render()
        return np.frombuffer(fbo.read(components=3, dtype="f4"), np.float32)

    t = timeit(frame, runs)
    return t, ctx.info["GL_RENDERER"]


def scenes(size: int):
    """(name, mesh, camera, material, cases) for each benchmark mesh; a case is
    (label, Render params, lights, extra inputs).  Shared with bench_render_backends.py."""
    from graphkit import Image, Light
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import FrameFace

    mat = PhongMaterial(diffuse=(0.6, 0.45, 0.3), specular=0.2, shininess=10.0)
    rng = np.random.default_rng(0)
    lights8 = []
    for i in range(8):
        az, el = rng.uniform(-60, 60), rng.uniform(-30, 40)
        a_, e_ = np.radians(az), np.radians(el)
        lights8.append(Light(direction=(np.sin(a_) * np.cos(e_), -np.sin(e_), -np.cos(a_) * np.cos(e_)),
                             intensity=0.25))
    one = [Light(direction=(0.3, -0.3, -0.9))]
    for name, mesh, cam0 in (face_mesh(), big_mesh()):
        cam = FrameFace(FrameFace.Params(size=size, margin=0.05)).compute(mesh=mesh, camera=cam0)["camera"]
        detail = Image(rng.uniform(0.8, 1.2, (cam0.height, cam0.width, 3)).astype(np.float32))
        cases = [
            ("1 light", dict(shadows=False), one, {}),
            ("1 light + shadow map", dict(shadows=True, shadow_map_size=512), one, {}),
            ("1 light + shadows + detail", dict(shadows=True, shadow_map_size=512), one,
             dict(detail=detail, texture_camera=cam0)),
            ("8 lights + shadows + detail + exposure 2", dict(shadows=True, shadow_map_size=512, exposure=2.0),
             lights8, dict(detail=detail, texture_camera=cam0)),
        ]
        yield name, mesh, cam, mat, cases


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    from nodes.paris.render import Render

    print(f"cores: {os.cpu_count()}, frame {a.size}×{a.size}, median of {a.runs} runs")
    for name, mesh, cam, mat, cases in scenes(a.size):
        print(f"\n{name}: {len(mesh.faces)} triangles")
        for label, params, lights, extra in cases:
            node = Render(Render.Params(eye_highlights="off", **params))
            t = timeit(lambda: node.compute(mesh=mesh, camera=cam, material=mat, lights=lights, **extra), a.runs)
            print(f"  numpy Render, {label:42s} {1 / t:7.2f} fps ({t * 1e3:7.1f} ms)")
        tp, who = peer_moderngl(mesh, cam, a.runs)
        if tp is None:
            print(f"  peer: {who}")
        else:
            node = Render(Render.Params(eye_highlights="off", shadows=False))
            one = cases[0][2]
            t1 = timeit(lambda: node.compute(mesh=mesh, camera=cam, material=mat, lights=one), a.runs)
            print(f"  peer moderngl ({who}), 1 light, per-pixel Phong + readback: {1 / tp:7.1f} fps "
                  f"({tp * 1e3:.1f} ms); numpy/peer time ratio {t1 / tp:.1f}×")


if __name__ == "__main__":
    main()
