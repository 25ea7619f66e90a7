"""The opengl backend of Render (plugins/graphkit-moderngl) against the numpy reference.

Directly in Python on scenes that exercise what the conformance examples do not: perspective-
correct interpolation on large receding triangles, a rotated off-centre camera, rotated
orthographic cameras (also as the texture camera, and with a world in mm: point lights in
metres), several directional and point lights with 1/d², exposure with and without the clamp, cast shadows on
and off (directional and point), a detail texture seen from another camera (occlusion), eye
highlights and a background.  Each case prints the image PSNR and the share of values outside
RenderGL.tolerance; both backends must agree within it.

Then through the real CLI: a graph pinning ``backend: opengl`` and a run preferring it
(``--backend opengl``) record "opengl" in manifest.json and match the numpy run;
``GRAPHKIT_OPENGL_DISABLE=1`` makes a pinned graph exit 2 with the reason and a preferred one
fall back to numpy with one notice line.  moderngl + EGL (Mesa llvmpipe) are installed by
``make``; an unavailable backend fails here (it is a broken set-up), it is not skipped.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from graphkit import Camera, Image, Light
from conftest import read_exr


def _classes():
    from graphkit.registry import default_registry

    reg = default_registry()
    assert "opengl" in reg.backend_names("Render"), (
        "Render has no 'opengl' backend: is plugins/graphkit-moderngl installed (make / pip install -e)?")
    return reg.node_class("Render"), reg.backend_class("Render", "opengl")


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> list[list[float]]:
    """World → camera (OpenCV axes: x right, y down, z forward)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    M = np.eye(4)
    M[:3, :3] = np.stack([x, y, z])
    M[:3, 3] = -M[:3, :3] @ eye
    return M.tolist()


def sphere(radius=1.0, centre=(0.0, 0.0, 4.0), sub=3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=sub, radius=radius)
    m.apply_translation(centre)
    return m


def floor_and_ball():
    """A 2×2-triangle wall behind a sphere: the sphere casts a shadow on the wall."""
    import trimesh

    wall = trimesh.Trimesh([[-1.8, -1.6, 6], [1.8, -1.6, 6], [1.8, 1.6, 6], [-1.8, 1.6, 6], [0, 0, 6]],
                           [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], process=False)
    return trimesh.util.concatenate([wall, sphere(0.8, (0.0, 0.0, 4.5))])


def receding_quad():
    """Two big triangles from z = 2 to z = 14: affine interpolation would be visibly wrong."""
    import trimesh

    return trimesh.Trimesh([[-1.5, 0.6, 2], [1.5, 0.6, 2], [1.5, 0.6, 14], [-1.5, 0.6, 14]],
                           [[0, 1, 2], [0, 2, 3]], process=False)


CAM = Camera(width=96, height=80, fx=110, fy=110, cx=48, cy=40)
MAT = {"diffuse": (0.6, 0.45, 0.35), "specular": 0.35, "shininess": 20.0}


def environment():
    """An environment's lighting: a key light, a light behind the face (it lights nothing: allowed
    for an environment's lights, as in numpy) and a side light that the ball shadows onto the
    wall, plus an SH ambient with all 9 coefficients set (each band changes the image)."""
    from nodes.paris.environment import EnvironmentLighting

    sh = np.array([[0.3, 0.25, 0.2], [0.05, 0.02, 0.0], [-0.08, -0.05, -0.02], [0.06, 0.07, 0.1],
                   [0.03, 0.0, -0.02], [-0.04, 0.02, 0.03], [0.05, 0.04, 0.02], [0.02, -0.03, 0.0],
                   [-0.05, 0.01, 0.04]])
    lights = (Light(direction=(0.3, -0.6, -0.74), color=(1.0, 0.9, 0.8), intensity=0.6),
              Light(direction=(0.0, 0.1, 1.0), intensity=2.0),
              Light(direction=(-0.7, 0.3, -0.65), color=(0.5, 0.6, 1.0), intensity=0.3))
    return EnvironmentLighting(lights=lights, sh=tuple(tuple(r) for r in sh))


def cases():
    from nodes.paris.models import PhongMaterial

    mat = PhongMaterial(**MAT)
    rot_cam = Camera(width=112, height=72, fx=95, fy=100, cx=61.3, cy=30.7,
                     world_to_camera=look_at((1.5, -0.8, -0.5), (0.0, 0.0, 4.0)))
    tex_cam = Camera(width=64, height=64, fx=80, fy=80, cx=32, cy=32,
                     world_to_camera=look_at((-1.2, 0.3, 0.2), (0.0, 0.0, 4.5)))
    detail = Image(np.random.default_rng(1).uniform(0.4, 1.6, (64, 64, 3)).astype(np.float32))
    key = Light(direction=(0.4, -0.5, -0.75))
    side = Light(direction=(-0.8, -0.2, -0.55), color=(1.0, 0.8, 0.6), intensity=0.8, ambient=(0.05, 0.05, 0.08))
    point = Light(kind="point", position=(1.5, -1.0, 1.0), color=(0.6, 0.8, 1.0), intensity=6.0)
    near_pt = Light(kind="point", position=(0.0, -0.2, 4.0), intensity=1.5)
    S = sphere()
    eyes = [[-0.33, -0.25, 3.06], [0.33, -0.25, 3.06]]
    # orthographic views: a rotated off-centre one in mm (metres_per_unit 0.001: point lights
    # are placed in metres) and an orthographic texture camera
    ortho_mm = Camera(width=104, height=80, projection="orthographic", pixels_per_m=32.0,
                      cx=50.3, cy=41.7, metres_per_unit=0.001,
                      world_to_camera=look_at((900.0, -500.0, -1200.0), (0.0, 0.0, 4000.0)))
    S_mm = sphere(1000.0, (0.0, 0.0, 4000.0))
    pt_m = Light(kind="point", position=(1.5, -1.0, 1.0), color=(0.6, 0.8, 1.0), intensity=6.0)
    ortho_tex = Camera(width=64, height=64, projection="orthographic", pixels_per_m=18.0, cx=32, cy=32,
                       world_to_camera=look_at((-1.2, 0.3, 0.2), (0.0, 0.0, 4.5)))
    return {
        "orthographic_rotated_mm_point_light_eyes": (
            {"shadow_map_size": 256, "eye_highlights": "on", "eyes": [[-330.0, -250.0, 3060.0], [330.0, -250.0, 3060.0]],
             "eye_shininess": 40.0, "background": (0.05, 0.1, 0.15)},
            {"mesh": S_mm, "camera": ortho_mm, "material": mat, "lights": [key, pt_m]}),
        "orthographic_texture_camera": (
            {"shadow_map_size": 256},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "lights": [key, point],
             "detail": detail, "texture_camera": ortho_tex}),
        "perspective_correct_point_light": (
            {"shadows": False},
            {"mesh": receding_quad(), "camera": CAM, "material": mat, "lights": [near_pt]}),
        "rotated_offcentre_camera_3_lights": (
            {"shadows": False, "background": (0.1, 0.2, 0.3)},
            {"mesh": S, "camera": rot_cam, "material": mat, "lights": [key, side, point]}),
        "exposure_clamp": (
            {"exposure": 3.0, "shadows": False},
            {"mesh": S, "camera": CAM, "material": mat, "lights": [key, side]}),
        "exposure_no_clamp": (
            {"exposure": 3.0, "clamp": False, "shadows": False},
            {"mesh": S, "camera": CAM, "material": mat, "lights": [key, side]}),
        "shadows_off": (
            {"shadows": False},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "lights": [key, point]}),
        "shadows_directional_and_point": (
            {"shadow_map_size": 256},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "lights": [key, point]}),
        "detail_texture_other_camera": (
            {"shadow_map_size": 256, "exposure": 1.5},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "lights": [key],
             "detail": detail, "texture_camera": tex_cam, "ambient": side}),
        "environment_only_shadows": (
            {"shadow_map_size": 256, "clamp": False, "environment_shadows": 0.0, "environment_basis": 0},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "environment": environment()}),
        # the default environment_shadows (0.2): the key light (0.27 of the brightest's
        # luminance) casts its shadow, the side light (0.09) lights the wall unshadowed
        "environment_dominant_shadows": (
            {"shadow_map_size": 256, "clamp": False, "environment_basis": 0},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat, "environment": environment()}),
        "environment_sh_only": (
            {"shadow_map_size": 256},
            {"mesh": floor_and_ball(), "camera": CAM, "material": mat,
             "environment": environment().model_copy(update={"lights": ()})}),
        "environment_and_lights_detail_eyes": (
            {"shadow_map_size": 256, "eye_highlights": "on", "eyes": eyes, "mm_per_unit": 100.0, "environment_basis": 0},
            {"mesh": S, "camera": rot_cam, "material": mat, "lights": [point], "environment": environment(),
             "detail": detail, "texture_camera": tex_cam}),
        "eye_highlights": (
            {"shadows": False, "clamp": False, "eye_highlights": "on", "eyes": eyes,
             "mm_per_unit": 100.0, "eye_shininess": 60.0},
            {"mesh": S, "camera": CAM, "material": mat, "lights": [Light(direction=(0.1, -0.2, -1.0), intensity=0.7), side]}),
    }


def psnr(ref, got) -> float:
    mse = float(np.mean((ref.astype(np.float64) - got) ** 2))
    peak = max(float(np.max(ref)), 1.0)
    return float("inf") if mse == 0 else 10 * np.log10(peak ** 2 / mse)


def arrays(out):
    return {"image": out["image"].pixels, "depth": out["depth"].pixels, "coverage": out["coverage"].alpha}


@pytest.mark.parametrize("name", list(cases()))
def test_opengl_matches_numpy(name):
    node, gl = _classes()
    assert gl.available(), gl.why_unavailable()
    params, inputs = cases()[name]
    p = node.Params.model_validate(params)
    ref, got = arrays(node(p).compute(**inputs)), arrays(gl(p).compute(**inputs))
    tol = {**node.tolerance, **gl.tolerance}
    cov = ref["coverage"] > 0
    assert 0.05 < cov.mean() < 1.0, "the scene must show both surface and background"
    for port in ref:
        assert got[port].shape == ref[port].shape and got[port].dtype == np.float32, port
        close = np.isclose(got[port], ref[port], rtol=tol["rtol"], atol=tol["atol"])
        bad = 1 - close.mean()
        print(f"{name} {port}: PSNR {psnr(ref[port], got[port]):.1f} dB, "
              f"{bad:.3%} outside rtol/atol, max |diff| {np.abs(got[port] - ref[port]).max():.2g}")
        assert bad <= tol["bad_fraction"], f"{port}: {bad:.3%} of values differ"
    assert psnr(ref["image"], got["image"]) > 45


def test_cases_exercise_what_they_claim():
    """Shadows darken, the texture and eyes change pixels, exposure saturates (in the reference:
    so the comparisons above are not vacuous)."""
    node, _ = _classes()
    c = cases()
    run = lambda n, **kw: node(node.Params.model_validate({**c[n][0], **kw})).compute(**c[n][1])["image"].pixels
    assert (run("shadows_off") - run("shadows_directional_and_point", shadow_map_size=256)).max() > 0.1
    assert np.abs(run("eye_highlights") - run("eye_highlights", eye_highlights="off")).max() > 0.1
    assert (run("exposure_clamp") == 1.0).any() and (run("exposure_no_clamp") > 1.0).any()
    env = c["environment_only_shadows"]
    no_sh = environment().model_copy(update={"sh": ((0.0, 0.0, 0.0),) * 9})
    bands = environment().model_copy(update={"sh": environment().sh[:1] + ((0.0, 0.0, 0.0),) * 8})
    for other in (no_sh, bands):  # the ambient, and its l ≥ 1 bands, show
        assert np.abs(run("environment_only_shadows") - node(node.Params.model_validate(env[0])).compute(
            **{**env[1], "environment": other})["image"].pixels).max() > 0.02
    assert (run("environment_only_shadows", shadows=False) - run("environment_only_shadows")).max() > 0.1
    # only the dominant light's shadow: the side light's is gone, the key light's stays
    assert (run("environment_dominant_shadows") - run("environment_only_shadows")).max() > 0.05
    assert (run("environment_dominant_shadows", shadows=False) - run("environment_dominant_shadows")).max() > 0.1
    assert np.abs(run("detail_texture_other_camera") - node(node.Params.model_validate(c["detail_texture_other_camera"][0])).compute(
        **{k: v for k, v in c["detail_texture_other_camera"][1].items() if k not in ("detail", "texture_camera")})["image"].pixels).max() > 0.1


def test_setup_kept_between_calls_changes_nothing():
    """With the engine's input digests (Context.inputs) Render/opengl keeps its light-independent
    set-up (glscene.scene ``key``) between calls: a call that changes only the lights, the
    material or the ambient must give exactly what a call without that memory gives, and other
    digests (another texture camera) another set-up."""
    from graphkit import Context

    node, gl = _classes()
    c = cases()
    for name in ("detail_texture_other_camera", "orthographic_rotated_mm_point_light_eyes"):
        params, inputs = c[name]
        p = node.Params.model_validate(params)
        dig = {k: f"{name}:{k}" for k in inputs if k not in ("lights", "material", "ambient")}
        dig.update(lights=["l1"], material="m1")
        ctx = Context(inputs=dig)
        first = arrays(gl(p, ctx).compute(**inputs))
        moved = {**inputs, "lights": [Light(direction=(-0.3, -0.4, -0.85), intensity=0.9)] + inputs["lights"][1:]}
        kept, fresh = arrays(gl(p, ctx).compute(**moved)), arrays(gl(p).compute(**moved))
        assert np.abs(kept["image"] - first["image"]).max() > 0.01, "the moved light must change the image"
        for port in fresh:
            assert np.array_equal(kept[port], fresh[port]), (name, port)
    params, inputs = c["detail_texture_other_camera"]
    p = node.Params.model_validate(params)
    other = {**inputs, "texture_camera": c["orthographic_texture_camera"][1]["texture_camera"]}
    dig = {k: f"tex:{k}" for k in ("mesh", "camera", "detail", "texture_camera")}
    gl(p, Context(inputs=dig)).compute(**inputs)
    got = arrays(gl(p, Context(inputs={**dig, "texture_camera": "tex:other"})).compute(**other))
    assert np.array_equal(got["image"], arrays(gl(p).compute(**other))["image"])


def test_surface_kept_between_light_changes():
    """Depth and coverage of a call on the same g-buffer (a light drag) come from the last such
    call (graphkit_moderngl.render.surface_key): they must equal what a call without that memory
    computes, be the call's own arrays (writing into one output changes no later one), and the
    light checks must still run on every call."""
    from graphkit import BadInput
    from graphkit_moderngl import render as R
    from graphkit_moderngl.runtime import runtime

    node, gl = _classes()
    c = cases()
    for name in ("detail_texture_other_camera", "orthographic_rotated_mm_point_light_eyes", "exposure_clamp"):
        params, inputs = c[name]
        p = node.Params.model_validate(params)
        first = gl(p).compute(**inputs)
        first["depth"].pixels[:] = -7.0  # a caller writing into its outputs
        first["coverage"].alpha[:] = 0.5
        moved = {**inputs, "lights": [Light(direction=(-0.3, -0.4, -0.85), intensity=0.9)] + inputs["lights"][1:]}
        kept = arrays(gl(p).compute(**moved))
        runtime().call(R._drop_surfaces)
        fresh = arrays(gl(p).compute(**moved))
        assert kept["coverage"].sum() > 0
        for port in fresh:
            assert np.array_equal(kept[port], fresh[port]), (name, port)
        if name == "exposure_clamp":  # (as test_bad_inputs_match_reference) the surface is kept: still checked
            with pytest.raises(BadInput, match="behind the face"):
                gl(p).compute(**{**inputs, "lights": [Light(direction=(0.0, 0.0, 1.0))]})


def test_split_alpha_target_same_as_rgba(monkeypatch):
    """The lighting pass writes its image into an RGB32F target and its alpha (± camera z) into
    an R32F one where the driver renders RGB32F (render._split_alpha), else both into one
    RGBA32F target: the two layouts must give the same bytes (every case, and one light with the
    eyes: the union box's corners that no pass draws must read as uncovered)."""
    from graphkit_moderngl import render as R
    from graphkit_moderngl.runtime import runtime

    node, gl = _classes()
    c = dict(cases())
    params, inputs = c["eye_highlights"]
    c["eye_highlights_one_light"] = (params, {**inputs, "lights": inputs["lights"][:1]})
    # an eye beyond the silhouette's corner, on a coloured background: the box shaded (the
    # union of the mesh's and the eyes' boxes) has corners that neither pass draws
    c["eye_outside_box"] = ({**params, "eyes": [[-1.3, -1.1, 3.4], [0.33, -0.25, 3.06]],
                             "background": (0.3, 0.2, 0.1)}, {**inputs, "lights": inputs["lights"][:1]})
    split_ok = runtime().call(R._split_alpha)
    if "llvmpipe" in runtime().describe():  # the driver `make test` installs renders RGB32F: the split
        assert split_ok                     # layout is the one compared here
    # (a driver without RGB32F targets: the flag cannot choose the split, both runs are RGBA32F)
    for name, (params, inputs) in c.items():
        p = node.Params.model_validate(params)
        got = {}
        for split in (True, False):
            monkeypatch.setattr(R, "SPLIT_ALPHA", split)
            runtime().call(R._drop_surfaces)  # depth and coverage from this layout's alpha
            got[split] = arrays(gl(p).compute(**inputs))
        for port in got[True]:
            assert np.array_equal(got[True][port], got[False][port]), (name, port)


def test_bad_inputs_match_reference():
    from graphkit import BadInput

    node, gl = _classes()
    params, inputs = cases()["exposure_clamp"]
    behind = {**inputs, "lights": [Light(direction=(0.0, 0.0, 1.0))]}
    for cls in (node, gl):
        with pytest.raises(BadInput, match="behind the face"):
            cls(node.Params.model_validate(params)).compute(**behind)
        with pytest.raises(BadInput, match="light 0 .* behind the face"):  # an environment's may be
            cls(node.Params.model_validate(params)).compute(**behind, environment=environment())
        with pytest.raises(BadInput, match="eyes are unknown"):
            cls(node.Params.model_validate({"eye_highlights": "on"})).compute(**inputs)


def test_what_gl_does_not_draw_is_refused():
    """antialias and mouth: photo (on a mediapipe mesh) are the numpy reference's only: the
    backend refuses them (BackendCannotRun: numpy instead, or exit 2 where pinned), never a
    silently different image; mouth: photo on a mesh that is not a mediapipe face draws."""
    from graphkit import BackendCannotRun

    node, gl = _classes()
    params, inputs = cases()["exposure_clamp"]
    with pytest.raises(BackendCannotRun, match="antialias"):
        gl(node.Params.model_validate({**params, "antialias": True})).compute(**inputs)
    face = inputs["mesh"].copy()
    src = np.full(len(face.vertices), -1)
    src[:468] = np.arange(468)  # a SmoothMesh of a FaceMesh keeps the 468 landmark ids
    face.vertex_attributes["source_vertex"] = src
    mp = {**inputs, "mesh": face}
    with pytest.raises(BackendCannotRun, match="mouth: photo"):
        gl(node.Params.model_validate(params)).compute(**mp)
    got = arrays(gl(node.Params.model_validate({**params, "mouth": "skin"})).compute(**mp))
    ref = arrays(node(node.Params.model_validate({**params, "mouth": "skin"})).compute(**mp))
    assert psnr(ref["image"], got["image"]) > 45
    arrays(gl(node.Params.model_validate(params)).compute(**inputs))  # no mediapipe ids: drawn


def test_threads_share_one_context():
    from concurrent.futures import ThreadPoolExecutor

    node, gl = _classes()
    params, inputs = cases()["exposure_clamp"]
    p = node.Params.model_validate(params)
    with ThreadPoolExecutor(4) as ex:
        outs = list(ex.map(lambda _: gl(p).compute(**inputs)["image"].pixels, range(6)))
    for o in outs[1:]:
        np.testing.assert_array_equal(o, outs[0])


# ----------------------------------------------------------------------------------------------
# through the CLI

GRAPH = """\
graphkit: 1
name: gl_{tag}
nodes:
  mesh: {{type: LoadMesh, params: {{path: ball.ply}}}}
  cam: {{type: LoadCameraJson, params: {{path: cam.json}}}}
  mat: {{type: TestMaterial}}
  key: {{type: MakeLight, params: {{azimuth_deg: 30.0, elevation_deg: 20.0}}}}
  fill: {{type: MakeLight, params: {{kind: point, position_m: [-3.0, 0.0, 0.0], color: [0.3, 0.5, 1.0], intensity: 9.0}}}}
  render:
    type: Render
    inputs: {{mesh: mesh.mesh, camera: cam.camera, material: mat.material, lights: [key.light, fill.light]}}
    params: {{exposure: 1.5, shadow_map_size: 128}}
{pin}  save:
    type: SaveImage
    inputs: {{image: render.image}}
    params: {{path: render.exr, bits: 32}}
outputs:
  image: save.file
"""

TEST_NODES = '''
from graphkit import Node, Out
from nodes.paris.models import PhongMaterial


class TestMaterial(Node):
    """A fixed skin material (test only)."""
    outputs = {"material": Out(PhongMaterial, "material")}

    def compute(self):
        return PhongMaterial(diffuse=(0.6, 0.45, 0.35), specular=0.3, shininess=15.0)


NODES = {"TestMaterial": TestMaterial}
'''


@pytest.fixture(scope="module")
def graph_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("opengl_graph")
    m = sphere()
    m.vertices[:] *= [0.8, 1.0, 0.9]
    m.vertices[:, 2] += 4.0 - m.vertices[:, 2].mean()
    m.export(d / "ball.ply")
    (d / "cam.json").write_text(json.dumps(CAM.model_dump()))
    (d / "glnodes.py").write_text(TEST_NODES)
    for tag, pin in (("free", ""), ("pinned", "    backend: opengl\n")):
        (d / f"{tag}.yaml").write_text(GRAPH.format(tag=tag, pin=pin))
    return d


def run_cli(d, graph, out, *args, env=None):
    e = {k: v for k, v in os.environ.items() if k not in ("GRAPHKIT_OPENGL_DISABLE", "GRAPHKIT_CACHE")}
    e["PYTHONPATH"] = os.pathsep.join([str(d), e.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    e["GRAPHKIT_PLUGINS"] = "glnodes:NODES"
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "graphkit", "run", str(d / graph), "--cache",
                           str(out) + "_cache", "--out", str(out), "-q", *args],
                          capture_output=True, text=True, env=e, timeout=120)


def backend_of(out):
    return json.loads((out / "manifest.json").read_text())["nodes"]["render"]["backend"]


@pytest.fixture(scope="module")
def numpy_exr(graph_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("numpy_run") / "out"
    p = run_cli(graph_dir, "free.yaml", out)
    assert p.returncode == 0, p.stderr
    assert backend_of(out) == "numpy"
    return read_exr(out / "render.exr")


@pytest.mark.parametrize(("graph", "args"), [("pinned.yaml", ()), ("free.yaml", ("--backend", "opengl"))],
                         ids=["pinned", "preferred"])
def test_cli_uses_opengl(graph_dir, numpy_exr, tmp_path, graph, args):
    p = run_cli(graph_dir, graph, tmp_path / "out", *args)
    assert p.returncode == 0, p.stderr
    assert "notice" not in p.stderr.lower()
    assert backend_of(tmp_path / "out") == "opengl"
    got = read_exr(tmp_path / "out" / "render.exr")
    close = np.isclose(got, numpy_exr, rtol=1e-3, atol=2e-3)
    assert got.shape == numpy_exr.shape and 1 - close.mean() <= 0.01


def test_cli_not_drawn(graph_dir, tmp_path):
    """antialias through the CLI: pinned to opengl, exit 2 naming the node, the backend and
    why; preferred, one notice and the numpy reference's bytes."""
    d = graph_dir
    for tag in ("pinned", "free"):
        text = (d / f"{tag}.yaml").read_text().replace("shadow_map_size: 128}", "shadow_map_size: 128, antialias: true}")
        (d / f"aa_{tag}.yaml").write_text(text)
    p = run_cli(d, "aa_pinned.yaml", tmp_path / "pinned")
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr + p.stdout
    assert "'render'" in p.stderr and "opengl" in p.stderr and "antialias" in p.stderr, p.stderr
    assert not (tmp_path / "pinned" / "render.exr").exists()
    p = run_cli(d, "aa_free.yaml", tmp_path / "pref", "--backend", "opengl")
    assert p.returncode == 0, p.stderr
    notices = [ln for ln in p.stderr.splitlines() if "notice" in ln.lower()]
    assert len(notices) == 1 and "antialias" in notices[0] and "numpy" in notices[0], p.stderr
    assert backend_of(tmp_path / "pref") == "numpy"
    q = run_cli(d, "aa_free.yaml", tmp_path / "ref")
    assert q.returncode == 0, q.stderr
    np.testing.assert_array_equal(read_exr(tmp_path / "pref" / "render.exr"), read_exr(tmp_path / "ref" / "render.exr"))


def test_cli_disabled(graph_dir, numpy_exr, tmp_path):
    off = {"GRAPHKIT_OPENGL_DISABLE": "1"}
    p = run_cli(graph_dir, "pinned.yaml", tmp_path / "pinned", env=off)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr + p.stdout
    assert "'render'" in p.stderr and "opengl" in p.stderr and "GRAPHKIT_OPENGL_DISABLE" in p.stderr, p.stderr
    assert not (tmp_path / "pinned" / "render.exr").exists()
    p = run_cli(graph_dir, "free.yaml", tmp_path / "pref", "--backend", "opengl", env=off)
    assert p.returncode == 0, p.stderr
    notices = [ln for ln in p.stderr.splitlines() if "notice" in ln.lower()]
    assert len(notices) == 1, p.stderr
    assert "opengl" in notices[0] and "GRAPHKIT_OPENGL_DISABLE" in notices[0] and "numpy" in notices[0]
    assert backend_of(tmp_path / "pref") == "numpy"
    np.testing.assert_array_equal(read_exr(tmp_path / "pref" / "render.exr"), numpy_exr)
