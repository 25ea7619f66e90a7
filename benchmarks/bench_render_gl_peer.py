"""Issue 14 benchmark (c): Render/opengl against a raw moderngl peer, same process, 512².

Peer: a bare moderngl program drawing the same mesh with a one-light Phong shader and a depth
test into a 512² RGBA32F framebuffer, read back as float32 (its buffers made once, as any
hand-written viewer would).  Render/opengl: ``RenderGL.compute`` on the same mesh, camera and
light (shadows and eye highlights off, as the peer; the full node call: host set-up, checks,
the GL passes and the float32 read-back of image, depth, coverage and lit masks), in three
regimes:

* ``light drag``: the light direction changes every frame (the studio's case: the kept
  g-buffer is reused, the lighting pass re-runs);
* ``same call``: identical inputs every frame;
* ``camera orbit``: the camera moves every frame (new vertex buffer and g-buffer each time).

Also the full Paris model (shadows 512², detail texture, eyes where known) while dragging.
Median and best of ``--runs`` frames after a warm-up; ratio = Render/opengl median / peer median
(goal of issue 14: ≤ 1.5×).  Run:  .venv/bin/python benchmarks/bench_render_gl_peer.py
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def times(fn, runs):
    fn()
    fn()
    ts = []
    for i in range(runs):
        t = time.perf_counter()
        fn(i)
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), min(ts)


class Peer:
    """One-light Phong in moderngl, drawn and read back (float32)."""

    def __init__(self, mesh, cam):
        import moderngl

        self.mgl = moderngl
        self.ctx = ctx = moderngl.create_standalone_context(backend="egl", require=330)
        W, H = cam.width, cam.height
        from peers import phong_peer

        vs, fs = phong_peer("330")
        self.prog = ctx.program(vertex_shader=vs, fragment_shader=fs)
        pix = cam.pixel_matrix()
        n, f = 0.1, 1e5
        P = np.zeros((4, 4))
        P[0] = 2 * pix[0] / W - pix[2]
        P[1] = 2 * pix[1] / H - pix[2]
        P[2] = [0, 0, (f + n) / (f - n), -2 * f * n / (f - n)]
        P[3] = pix[2]
        self.prog["P"].write(P.T.astype("f4").tobytes())
        self.prog["kd"].value = (0.6, 0.45, 0.3)
        self.prog["ks"].value = 0.2
        self.prog["s"].value = 10.0
        V = cam.to_camera(np.asarray(mesh.vertices, np.float64)).astype(np.float32)
        N = (np.asarray(mesh.vertex_normals) @ cam.rotation.T).astype(np.float32)
        self.vbo = ctx.buffer(np.hstack([V, N]).tobytes())
        self.ibo = ctx.buffer(np.asarray(mesh.faces, np.int32).tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "3f 3f", "pos", "nrm")], self.ibo)
        self.fbo = ctx.simple_framebuffer((W, H), components=4, dtype="f4")
        self.cam = cam

    def frame(self, light_dir):
        l_cam = self.cam.rotation @ np.asarray(light_dir, np.float64)
        self.prog["L"].value = tuple(l_cam / np.linalg.norm(l_cam))
        self.fbo.use()
        self.ctx.enable(self.mgl.DEPTH_TEST)
        self.fbo.clear(0, 0, 0, 1, depth=1.0)
        self.vao.render()
        return np.frombuffer(self.fbo.read(components=4, dtype="f4"), np.float32)


def drag_dirs(k=64):
    a = np.linspace(-0.6, 0.6, k)
    return [np.array([np.sin(t), -0.3, -np.cos(t)]) for t in a]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    from bench_render import big_mesh, face_mesh

    from graphkit import Camera, Image, Light
    from graphkit.registry import default_registry
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import FrameFace

    reg = default_registry()
    GL = reg.backend_class("Render", "opengl")
    Render = reg.node_class("Render")
    from graphkit_moderngl.runtime import runtime

    print(f"frame {a.size}², median / best of {a.runs} frames, OpenGL: {runtime().describe()}")
    mat = PhongMaterial(diffuse=(0.6, 0.45, 0.3), specular=0.2, shininess=10.0)
    dirs = drag_dirs()
    rows = []
    for name, mesh, cam0 in (face_mesh(), big_mesh()):
        cam = FrameFace(FrameFace.Params(size=a.size, margin=0.05)).compute(mesh=mesh, camera=cam0)["camera"]
        peer = Peer(mesh, cam)
        pm, pb = times(lambda i=0: peer.frame(dirs[i % len(dirs)]), a.runs)
        node = GL(Render.Params(shadows=False, eye_highlights="off"))

        def call(i=0, camera=cam, n=node, extra=None):
            return n.compute(mesh=mesh, camera=camera, material=mat,
                             lights=[Light(direction=tuple(dirs[i % len(dirs)]))], **(extra or {}))

        # an orbit: the camera turns about the mesh centre by a small angle each frame
        c = np.asarray(mesh.vertices).mean(axis=0)
        orbit = []
        for t in np.linspace(-0.05, 0.05, 16):
            R = np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
            M = np.asarray(cam.pose, np.float64).copy()
            M[:3, :3] = cam.rotation @ R
            M[:3, 3] = cam.pose[:3, 3] + cam.rotation @ c - M[:3, :3] @ c
            orbit.append(cam.model_copy(update={"world_to_camera": M.tolist()}) if hasattr(cam, "model_copy")
                         else Camera(**{**cam.__dict__, "world_to_camera": M.tolist()}))
        res = {"light drag": times(call, a.runs),
               "same call": times(lambda i=0: call(0), a.runs),
               "camera orbit": times(lambda i=0: call(0, orbit[i % len(orbit)]), a.runs)}
        full = GL(Render.Params(shadow_map_size=512))
        rng = np.random.default_rng(0)
        detail = Image(rng.uniform(0.8, 1.2, (cam0.height, cam0.width, 3)).astype(np.float32))
        res["full Paris model, light drag"] = times(
            lambda i=0: call(i, n=full, extra={"detail": detail, "texture_camera": cam0}), a.runs)
        print(f"\n{name}: {len(mesh.faces)} triangles; peer {1e3 * pm:.2f} ms median, {1e3 * pb:.2f} ms best "
              f"({1 / pm:.0f} fps)")
        for k, (m, b) in res.items():
            print(f"  Render/opengl {k:30s} {1e3 * m:7.2f} ms median {1e3 * b:7.2f} ms best "
                  f"({1 / m:5.0f} fps)  ratio {m / pm:4.2f}× median, {b / pb:4.2f}× best")
            rows.append((name, k, m, b, pm, pb))
    return 0


if __name__ == "__main__":
    sys.exit(main())
