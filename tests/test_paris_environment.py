"""Relighting to an environment (issue 26 item 4): LoadEnvironment, EnvironmentLights and
Render's ``environment`` port.

Energy and SH irradiance against analytic integrals; orientation and rotation against a map
rolled by hand; the relit head against Mitsuba 3 renders of the same head under the same
``envmap`` emitter (tests/data/envmap_refs.npz, from nodes/paris/data/make_envmaps.py; the
TUNE maps chose EnvironmentLights' defaults, the CHECK maps only check them); bad maps through
the CLI (exit 2, nothing written)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import BadInput
from graphkit.contract import compute_checked
from nodes.io.environment import EnvironmentFrame, LoadEnvironment, local_directions, read_hdr, solid_angles
from nodes.paris.data import make_envmaps as E
from nodes.paris.environment import (EnvironmentLights, map_energy, sh_irradiance)

H = 64


_lighting = E.lighting


def near_fraction(disc) -> float:
    """The solid angle of the disc's pixels / 4π."""
    return float((solid_angles(H, 2 * H) * (disc[..., 0] > 0)).sum() / (4 * np.pi))


def _analytic_maps():
    """(name, H×2H×3 map, its exact ∫ L dω per channel)."""
    d = local_directions(H, 2 * H)
    up = d[..., 1]
    cos_lobe = np.repeat(np.clip(up, 0, None)[..., None], 3, 2)  # ∫ max(0, cos θ) dω = π
    disc = np.zeros((H, 2 * H, 3))
    near = d @ np.array([0.6, 0.48, 0.64]) > np.cos(np.radians(12))  # a 12° cap, pixel-exact area below
    disc[near] = (50.0, 40.0, 30.0)
    disc_true = np.array([50.0, 40.0, 30.0]) * float((solid_angles(H, 2 * H) * near).sum())
    sky = 0.1 + 0.2 * cos_lobe + disc
    return [("uniform", np.full((H, 2 * H, 3), 0.7), np.full(3, 0.7 * 4 * np.pi)),
            ("cosine", cos_lobe, np.full(3, np.pi)),
            ("disc", disc, disc_true),
            ("sky", sky, 0.1 * 4 * np.pi + 0.2 * np.pi + disc_true)]


@pytest.mark.parametrize("lights", [0, 4, 16])
def test_lights_and_ambient_hold_the_maps_energy(lights):
    """The dominant lights' energy plus the ambient's is within 3 % of the map's solid-angle
    integral (by construction it is exact: 1e-5 asserted), and map_energy of analytic maps is
    their known integral within 1 % (the pixel grid's only error)."""
    for name, px, true in _analytic_maps():
        np.testing.assert_allclose(map_energy(px), true, rtol=0.01, err_msg=name)
        env = _lighting(px, lights=lights)
        assert np.all(np.abs(env.energy() / true - 1) < 0.03), name
        np.testing.assert_allclose(env.energy(), map_energy(px), rtol=1e-5, err_msg=name)
        if name == "disc" and lights:
            # the lights take what stands above 2 × the mean: here 1 − 2 × (cap / 4π) = 97.8 %
            in_lights = sum(np.pi * x.intensity * np.asarray(x.color) for x in env.lights)
            np.testing.assert_allclose(in_lights / true, 1 - 2 * float(near_fraction(px)), rtol=1e-6)
        if name == "uniform":
            assert env.lights == ()  # nothing stands out of a uniform map


def test_median_cut_light_points_at_the_disc_and_sh_irradiance_is_the_integral():
    """A bright disc becomes lights along its centre (the energy-weighted mean within 1°); the
    SH ambient of an order-2 radiance gives the irradiance of a brute-force integral."""
    _, disc, _ = _analytic_maps()[2]
    env = _lighting(disc, lights=4)
    c = sum(np.asarray(light.direction) * light.intensity for light in env.lights)
    c_local = np.array([0.6, 0.48, 0.64])  # (right, up, centre) → world (x, −y, z)
    want = np.array([c_local[0], -c_local[1], c_local[2]])
    assert np.degrees(np.arccos(np.dot(c / np.linalg.norm(c), want))) < 1.0
    d = local_directions(256, 512) @ EnvironmentFrame().matrix().T
    L = 1 + 0.5 * d[..., 1] + 0.3 * d[..., 0] * d[..., 2]  # world-frame order-2 radiance
    px_local = np.repeat(L[..., None], 3, 2)
    env = _lighting(px_local, lights=0, width=512)
    om = solid_angles(256, 512)
    for n in (np.array([0.0, 0.0, -1.0]), np.array([0.0, -1.0, 0.0]), np.array([0.6, 0.0, 0.8])):
        brute = float((L * np.clip(d @ n, 0, None) * om).sum()) / np.pi
        np.testing.assert_allclose(sh_irradiance(env.sh, n[None])[0], brute, rtol=2e-3)


def test_rotation_turns_the_centre_towards_the_right(tmp_path):
    """rotation_deg 90 equals the map rolled a quarter turn: the same lights and SH; with a
    camera the frame is the camera's (up = the camera's −y)."""
    from graphkit import Camera
    from graphkit.node import Context

    px = read_hdr(E.HERE + "/envmaps/window.exr")
    node = LoadEnvironment(LoadEnvironment.Params(path="builtin:envmaps/window.exr", rotation_deg=90.0),
                           Context())
    out = node.compute()
    f = out["frame"]
    np.testing.assert_allclose(f.centre, (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(f.right, (0, 0, -1), atol=1e-12)
    # the map rolled right by a quarter turn, in the unrotated frame, is the same environment
    rolled = np.roll(px, px.shape[1] // 4, axis=1)
    a = compute_checked(EnvironmentLights(), image=out["image"], frame=f)
    b = _lighting(rolled)
    np.testing.assert_allclose(a.sh, b.sh, atol=1e-6)
    np.testing.assert_allclose(sorted(x.direction for x in a.lights), sorted(x.direction for x in b.lights), atol=1e-6)
    cam = Camera(width=8, height=8, fx=8, fy=8, cx=4, cy=4,
                 world_to_camera=[[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]])
    f = LoadEnvironment(LoadEnvironment.Params(path="builtin:envmaps/window.exr"), Context()).frame(cam)
    np.testing.assert_allclose(f.centre, cam.forward, atol=1e-12)


@pytest.mark.parametrize("name", E.TUNE + E.CHECK)
def test_relit_head_matches_mitsuba_under_the_same_envmap(name):
    """Render + EnvironmentLights against Mitsuba's render of the same diffuse head under the
    map as an ``envmap``: ≥ 30 dB on the head; the map mirrored left-right (a wrong
    orientation) is far off (< 25 dB)."""
    refs = np.load(E.REFS)
    px = read_hdr(E.HERE + f"/envmaps/{name}.exr")
    img, cover = E.relight(px)
    assert E.skin_psnr(img, refs[name], cover) >= 30.0
    wrong, _ = E.relight(px[:, ::-1].copy())
    assert E.skin_psnr(wrong, refs[name], cover) < 25.0


def test_render_takes_an_environment_without_lights_and_refuses_neither():
    from nodes.paris.data.make_capture import camera, head_mesh
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import Render

    m, _, _ = head_mesh(2)
    mat = PhongMaterial(diffuse=E.ALBEDO, specular=0.0)
    with pytest.raises(BadInput) as e:
        compute_checked(Render(), mesh=m, camera=camera(16), material=mat, lights=[])
    assert e.value.port == "lights" and "needs at least 1 connection, got 0" in e.value.message
    env = _lighting(np.full((64, 128, 3), 1.0))  # uniform radiance 1: a white surface shows 1
    out = compute_checked(Render(Render.Params(clamp=False, eye_highlights="off")), mesh=m, camera=camera(16),
                          material=PhongMaterial(diffuse=(1.0, 1.0, 1.0), specular=0.0), environment=env)
    cov = out["coverage"].alpha > 0
    np.testing.assert_allclose(out["image"].pixels[cov], 1.0, rtol=1e-3)  # l = 2 terms of the pixel grid


def test_dimmer_environment_lights_take_smaller_shadow_maps(monkeypatch):
    """An environment light's shadow map: the brightest's side × (luminance ratio)^⅓, at least
    an eighth of it, or none below ``dominant`` × the brightest's luminance (Render's
    environment_shadows); the lights on ``lights`` keep ``shadow_map_size`` however dim.
    (Render with ``environment_basis: 0``, shadow maps per light; the GL backend's rule.)"""
    from graphkit import Light
    from nodes.common import raster
    from nodes.paris.data.make_capture import camera, head_mesh
    from nodes.paris.environment import EnvironmentLighting, shadow_map_sizes
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import Render

    front = (0.0, 0.0, -1.0)
    env = EnvironmentLighting(lights=tuple(Light(direction=front, intensity=i, color=(1.0, 1.0, 1.0))
                                           for i in (8.0, 1.0, 8 / 27, 1e-6)))
    assert shadow_map_sizes(env.lights, 1024) == [1024, 512, 341, 128]
    assert shadow_map_sizes(env.lights[1:2], 1024) == [1024]  # alone, it is the brightest
    # lights given as such (the first ``own``) keep the full map; the rest are sized among themselves
    assert shadow_map_sizes(env.lights, 1024, own=2) == [1024, 1024, 1024, 128]
    # only the dominant ones cast a shadow (side 0: none), and always the brightest
    assert shadow_map_sizes(env.lights, 1024, dominant=0.125) == [1024, 512, 0, 0]
    assert shadow_map_sizes(env.lights, 1024, dominant=1.0) == [1024, 0, 0, 0]
    assert shadow_map_sizes(env.lights, 1024, own=2, dominant=0.5) == [1024, 1024, 1024, 0]
    sizes = []
    real = raster.shadow_map
    monkeypatch.setattr(raster, "shadow_map", lambda V, F, light, size, **kw: sizes.append(size) or real(V, F, light, size, **kw))
    m, _, _ = head_mesh(2)
    for dominant, want in ((0.0, [96, 96, 48, 32, 16]),  # 96 / 8 = 12 → 16 (the least map)
                           (0.2, [96, 96])):  # the default: the dim ones cast none
        sizes.clear()
        compute_checked(Render(Render.Params(shadow_map_size=96, environment_shadows=dominant,
                                             environment_basis=0)), mesh=m,  # (shadow maps, not the basis)
                        camera=camera(16), material=PhongMaterial(diffuse=E.ALBEDO),
                        lights=[Light(direction=front, intensity=1e-6)], environment=env)
        assert sorted(sizes) == sorted(want)


GRAPH = """graphkit: 1
nodes:
  env: {type: LoadEnvironment, params: {path: MAP}}
  lit: {type: EnvironmentLights, inputs: {image: env.image, frame: env.frame}}
outputs:
  map: env.image
"""


def _write(path, px, fmt="float"):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], fmt))
    out.write_image(px)
    out.close()


@pytest.mark.parametrize("case, say", [
    ("square", "twice as wide as high (2:1)"),
    ("nan", "1 NaN, 0 Inf and 0 negative values"),
    ("negative", "0 NaN, 0 Inf and 2 negative values"),
    ("png", "stores uint8 values, not HDR radiance"),
])
def test_bad_maps_exit_2_naming_node_and_port_and_write_nothing(tmp_path, case, say):
    from conftest import graphkit

    px = np.full((8, 16, 3), 0.5, np.float32)
    name = "m.exr"
    if case == "square":
        px = np.full((8, 8, 3), 0.5, np.float32)
    elif case == "nan":
        px[1, 2, 0] = np.nan
    elif case == "negative":
        px[3, 3, :2] = -1
    if case == "png":
        name = "m.png"
        _write(tmp_path / name, (px * 255).astype(np.uint8), "uint8")
    else:
        _write(tmp_path / name, px)
    (tmp_path / "g.yaml").write_text(GRAPH.replace("MAP", name))
    r = graphkit("run", tmp_path / "g.yaml", "--cache", tmp_path / "cache", "--out", tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "node 'env' (LoadEnvironment), port 'path'" in r.stderr and say in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


STUDIO_GRAPH = """graphkit: 1
nodes:
  mesh: {type: LoadMesh, params: {path: "builtin:sample_capture/mesh.ply"}}
  cam: {type: LoadCameraJson, params: {path: "builtin:sample_capture/camera.json"}}
  environment:
    type: LoadEnvironment
    inputs: {camera: cam.camera}
    params: {path: "builtin:envmaps/window.exr", rotation_deg: 0.0}
  lighting: {type: EnvironmentLights, inputs: {image: environment.image, frame: environment.frame}}
  relit:
    type: Render
    inputs: {mesh: mesh.mesh, camera: cam.camera, material: mat.material,
             environment: lighting.lighting}
    params: {shadow_map_size: 256}
  photo: {type: LoadImage, params: {path: "builtin:sample_capture/photo.exr"}}
  face: {type: MeshMask, inputs: {mesh: mesh.mesh, camera: cam.camera}}
  skin: {type: SkinSegment, inputs: {image: photo.image, face: face.mask}}
  flash: {type: MakeLight, inputs: {camera: cam.camera}}
  mat:
    type: FitSkinPhong
    inputs: {image: photo.image, skin: skin.mask, mesh: mesh.mesh, camera: cam.camera, light: flash.light}
    params: {starts: 1, seed: 0}
  save: {type: SaveImage, inputs: {image: relit.image}, params: {path: relit.exr}}
outputs:
  relit: save.file
"""


def test_the_studio_turns_the_environment_and_the_render_follows(tmp_path):
    """Python-level studio: rotation_deg is a bounded number (the param panel draws it as a
    slider, controls.js), and changing it re-runs the environment, its lights and the render,
    which changes."""
    from conftest import read_exr

    from graphkit.studio.core import Studio

    p = tmp_path / "g.yaml"
    p.write_text(STUDIO_GRAPH)
    st = Studio(p, cache=str(tmp_path / "c"), out=str(tmp_path / "o"))
    try:
        assert st.wait_idle(120)["status"] == "ok"
        before = read_exr(tmp_path / "o" / "relit.exr")
        schema = st.state()["schemas"]["LoadEnvironment"]["params"]["properties"]["rotation_deg"]["anyOf"][0]
        assert (schema["type"], schema["minimum"], schema["maximum"]) == ("number", -360, 360)
        assert st.set_params([{"node": "environment", "param": "rotation_deg", "value": 120.0}])["ok"]
        info = st.wait_idle(120)
        assert info["status"] == "ok" and info["computed"] == ["environment", "lighting", "relit", "save"], info
        after = read_exr(tmp_path / "o" / "relit.exr")
        assert np.abs(after - before).max() > 0.05
        # Render's WebGL live view does not draw the SH ambient: it refuses, naming the port
        from nodes.paris.studio_view import FaceView

        with pytest.raises(BadInput) as e:
            FaceView(st, "relit").data()
        assert e.value.port == "environment"
    finally:
        st.close()


def test_a_radiance_hdr_map_is_read(tmp_path):
    """Radiance .hdr (RGBE) as well as OpenEXR: the values come back within RGBE's 8-bit mantissa
    (of the pixel's largest channel: the exponent is shared)."""
    px = np.random.default_rng(0).uniform(0, 3, (8, 16, 3)).astype(np.float32)
    _write(tmp_path / "m.hdr", px)
    err = np.abs(read_hdr(str(tmp_path / "m.hdr")) - px)
    assert np.all(err <= px.max(2, keepdims=True) / 64)


def test_the_first_light_whose_shadow_map_fails_is_named_however_the_cores_ran(monkeypatch):
    """Shadow maps run on the cores, dealt by cost: of two lights whose shadow map fails, the
    first is named, even when the second failed first (it had the smaller map, or its core
    was free sooner)."""
    import time

    from graphkit import Light
    from nodes.common import raster
    from nodes.paris.data.make_capture import camera, head_mesh
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import Render

    real = raster.shadow_map

    def failing(V, F, light, size, **kw):
        if light.intensity < 1:  # lights 1 (0.5, slow) and 2 (0.25) fail
            time.sleep(0.3 if light.intensity == 0.5 else 0.0)
            raise ValueError(f"fails ({light.intensity})")
        return real(V, F, light, size, **kw)

    monkeypatch.setattr(raster, "shadow_map", failing)
    m, _, _ = head_mesh(2)
    front = (0.0, 0.0, -1.0)
    with pytest.raises(BadInput) as e:
        compute_checked(Render(Render.Params(shadow_map_size=64)), mesh=m, camera=camera(16),
                        material=PhongMaterial(diffuse=E.ALBEDO),
                        lights=[Light(direction=front, intensity=i) for i in (1.0, 0.5, 0.25, 1.0)])
    assert (e.value.port, e.value.message) == ("lights", "light 1: fails (0.5)")
