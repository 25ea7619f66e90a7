"""One GLSL source for moderngl and WebGL2 (graphkit/glsl.py) and Render/opengl's GL objects
kept between calls (plugins/graphkit-moderngl, runtime.GLObjects).

* Every program of shaders/glsl/ builds for both targets: GLSL 3.30 core, and GLSL ES 3.00 as
  WebGL2 gets it (Mesa's desktop contexts compile ``#version 300 es`` through
  ARB_ES3_compatibility, the same front end as its GLES driver).
* The preprocessor refuses, with file:line, a construct outside the shared subset, a missing
  include and an include cycle; a define is placed after the version line.
* Persistence: the same mesh lit by light A, then B, then A again (shadows, detail texture,
  eyes) matches the numpy reference every time — a stale g-buffer/shadow atlas would show the
  previous light — and a repeated call creates no GL object.
"""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import Camera, Image, Light
from graphkit.glsl import GlslError, files, source

PROGRAMS = [
    ("depth.vert", "depth.frag", {}),
    ("depth.vert", "depth.frag", {"WORLD": 1, "DEPTH_ONLY": 1}),
    ("gbuffer.vert", "gbuffer.frag", {"DETAIL": 1, "ORTHO": 0}),
    ("gbuffer.vert", "gbuffer.frag", {"DETAIL": 0, "ORTHO": 1}),
    ("screen.vert", "shade.frag", {"N_LIGHTS": 3, "SHADOWS": 1, "EYES": 1, "ORTHO": 0, "LIT_MASKS": 1}),
    ("screen.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 1, "EYES": 1, "ORTHO": 0, "SM_WINDOW": 1}),
    ("screen.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 0, "EYES": 0, "ORTHO": 1}),
    ("screen.vert", "display.frag", {}),
    ("screen.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 1, "EYES": 1, "SM_WINDOW": 1, "DISPLAY": 1}),
    ("rects.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 1, "EYES": 0, "SM_WINDOW": 1, "DISPLAY": 1,
                                  "DIRECTIONAL": 1}),
    # the studio's: the PCF as depth-compare samples (sampler2DShadow)
    ("rects.vert", "shade.frag", {"N_LIGHTS": 1, "SHADOWS": 1, "EYES": 0, "SM_WINDOW": 1, "SM_BILINEAR": 1,
                                  "DISPLAY": 1, "DIRECTIONAL": 1}),
    ("screen.vert", "shade.frag", {"N_LIGHTS": 2, "SHADOWS": 1, "EYES": 1, "SM_WINDOW": 1, "SM_BILINEAR": 1}),
]


@pytest.fixture(scope="module")
def rt():
    from graphkit_moderngl.runtime import runtime

    return runtime()


@pytest.mark.parametrize("target", ["330", "es300"])
def test_every_program_builds_for_both_targets(rt, target):
    def build(r):
        out = []
        for v, f, d in PROGRAMS:
            vs, fs = source(v, target, d), source(f, target, d)
            assert vs.splitlines()[0] == ("#version 300 es" if target == "es300" else "#version 330 core")
            p = r.ctx.program(vertex_shader=vs, fragment_shader=fs)
            out.append(len(list(p)))
            p.release()
        return out

    assert all(n >= 1 for n in rt.call(build))


def test_includes_and_defines():
    s = source("shade.frag", "es300", {"N_LIGHTS": 4, "SHADOWS": True})
    lines = s.splitlines()
    assert lines[0] == "#version 300 es" and "precision highp float;" in lines
    assert "#define N_LIGHTS 4" in lines and "#define SHADOWS 1" in lines
    assert lines.index("#define N_LIGHTS 4") < next(i for i, l in enumerate(lines) if "light_kind" in l)
    assert not any(l.strip().startswith("#include") for l in lines)
    assert files("shade.frag") == ["shade.frag", "lights.glsl", "srgb.glsl"]
    assert "precision" not in source("shade.frag", "330")


@pytest.mark.parametrize(("text", "want"), [
    ("#version 330\ndouble x;\nvoid main() {}\n", "bad.frag:2: double"),
    ("#version 330\nuniform sampler1D s;\nvoid main() {}\n", "bad.frag:2: a sampler type"),
    ("#version 330\nvoid main() { gl_FragColor = vec4(1.0); }\n", "bad.frag:2: pre-1.30"),
    ("#version 330\n#include \"missing.glsl\"\n", "missing.glsl not found"),
    ("#version 330\n#include \"cyc.glsl\"\n", "include cycle"),
    ("#version 300 es\nvoid main() {}\n", "bad.frag:1: a shader starts with '#version 330'"),
])
def test_refusals_name_file_and_line(tmp_path, monkeypatch, text, want):
    import graphkit.glsl as glsl

    d = tmp_path / "glsl"
    d.mkdir()
    (d / "bad.frag").write_text(text)
    (d / "cyc.glsl").write_text('#include "cyc2.glsl"\n')
    (d / "cyc2.glsl").write_text('#include "cyc.glsl"\n')
    monkeypatch.setenv("GRAPHKIT_SHADERS", str(tmp_path))
    monkeypatch.setattr(glsl, "_memo", {})
    with pytest.raises(GlslError, match=want.replace("(", r"\(").replace(".", r"\.")):
        source("bad.frag")
    with pytest.raises(GlslError):
        source("shade.frag", "gles")
    with pytest.raises(GlslError):
        source("shade.frag", "330", {"bad name": 1})


def _scene():
    import trimesh
    from nodes.paris.models import PhongMaterial

    wall = trimesh.Trimesh([[-1.8, -1.6, 6], [1.8, -1.6, 6], [1.8, 1.6, 6], [-1.8, 1.6, 6], [0, 0, 6]],
                           [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], process=False)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    ball.apply_translation((0.0, 0.0, 4.5))
    mesh = trimesh.util.concatenate([wall, ball])
    cam = Camera(width=96, height=80, fx=110, fy=110, cx=48, cy=40)
    tex_cam = Camera(width=64, height=64, fx=80, fy=80, cx=32, cy=32)
    detail = Image(np.random.default_rng(3).uniform(0.5, 1.5, (64, 64, 3)).astype(np.float32))
    mat = PhongMaterial(diffuse=(0.6, 0.45, 0.35), specular=0.35, shininess=20.0)
    return mesh, cam, tex_cam, detail, mat


def test_kept_objects_follow_the_inputs(rt):
    from graphkit.registry import default_registry

    reg = default_registry()
    node, gl = reg.node_class("Render"), reg.backend_class("Render", "opengl")
    tol = {**node.tolerance, **gl.tolerance}
    mesh, cam, tex_cam, detail, mat = _scene()
    p = node.Params(shadow_map_size=128, eye_highlights="on", eyes=[[-0.3, -0.2, 3.75], [0.3, -0.2, 3.75]],
                    mm_per_unit=100.0)
    A = Light(direction=(0.4, -0.5, -0.75))
    B = Light(direction=(-0.6, 0.3, -0.75), color=(1.0, 0.8, 0.6))
    ref, glb = node(p), gl(p)

    def both(light, m=mat):
        kw = dict(mesh=mesh, camera=cam, material=m, lights=[light], detail=detail, texture_camera=tex_cam)
        return ref.compute(**kw)["image"].pixels, glb.compute(**kw)["image"].pixels

    store = rt.objects
    images = []
    for light in (A, B, A):
        x, y = both(light)
        bad = 1 - np.isclose(y, x, rtol=tol["rtol"], atol=tol["atol"]).mean()
        assert bad <= tol["bad_fraction"], (light, bad)
        images.append(y)
    assert np.abs(images[0] - images[1]).max() > 0.1  # the light change is visible
    np.testing.assert_array_equal(images[0], images[2])
    # a changed material only re-runs the lighting pass, and still matches
    from nodes.paris.models import PhongMaterial

    x, y = both(A, PhongMaterial(diffuse=(0.2, 0.5, 0.7), specular=0.1, shininess=5.0))
    assert 1 - np.isclose(y, x, rtol=tol["rtol"], atol=tol["atol"]).mean() <= tol["bad_fraction"]
    n, misses = len(store), store.misses
    both(A)
    assert store.misses == misses and len(store) == n  # nothing new built for a repeated call
