"""Soft shadows (issue 26 item 2): lights with a size, percentage-closer soft shadows in the
numpy reference, checked against Mitsuba 3's penumbrae (profiles stored by
benchmarks/soft_shadow_reference.py --write), and the opengl backend's refusal."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import soft_shadow_reference as ref  # noqa: E402

from graphkit import BadInput, Light  # noqa: E402
from nodes.common.raster import shadow_map  # noqa: E402
from nodes.common.shadows import light_visibility, soft_visibility  # noqa: E402
from nodes.paris.render import LightSize, Render  # noqa: E402

STORED = json.loads(ref.PROFILES.read_text())


@pytest.mark.parametrize("name", sorted(ref.CHECK))
def test_penumbra_width_within_20_percent_of_mitsuba(name):
    """The check cases (not used to choose the filter): 10–90 % widths within 20 %."""
    case = STORED["cases"][name]
    assert case["set"] == "check"
    shape, dist, radius = ref.CHECK[name]
    s = ref.case_geometry(shape, dist)[3]
    mitsuba = np.asarray(case["mitsuba"])
    ours = ref.ours_profile(shape, dist, radius)
    wm, wo = ref.width_10_90(s, mitsuba), ref.width_10_90(s, ours)
    assert np.isfinite(wm) and wm > 0.04, "the line must start in the umbra and cross a penumbra"
    assert abs(wo / wm - 1) <= 0.2, f"{name}: penumbra {wo:.4f}, Mitsuba's {wm:.4f}"
    # the whole profile, not only its width: mean |difference| of the lit fraction
    assert np.abs(ours - mitsuba).mean() < 0.03


def test_stored_profiles_are_the_script_cases():
    """The stored reference holds the script's tune and check cases with their settings."""
    assert set(STORED["cases"]) == set(ref.TUNE) | set(ref.CHECK)
    assert not set(ref.TUNE) & set(ref.CHECK)
    for name, (shape, dist, radius) in {**ref.TUNE, **ref.CHECK}.items():
        c = STORED["cases"][name]
        assert (c["shape"], c["distance"]) == (shape, dist) and c["radius"] == pytest.approx(radius)
        assert len(c["mitsuba"]) == ref.POINTS == STORED["points"]


def test_penumbra_grows_with_the_light_and_a_point_light_stays_hard():
    shape, dist = "sphere", 10.0
    s = ref.case_geometry(shape, dist)[3]
    widths = [ref.width_10_90(s, ref.ours_profile(shape, dist, r)) for r in (0.25, 0.5, 1.0)]
    assert widths[0] < widths[1] < widths[2]
    assert widths[2] / widths[0] == pytest.approx(4.0, rel=0.25)  # ∝ the light's radius
    mesh, light, line, _ = ref.case_geometry(shape, dist)
    sm = shadow_map(mesh.vertices, mesh.faces, Light(kind="point", position=tuple(light)), 1024)
    hard = light_visibility(sm, Light(kind="point", position=tuple(light)), line, np.tile([0, 0, 1.0], (len(line), 1)))
    assert ref.width_10_90(s, hard) < 0.3 * widths[0]


def test_a_light_without_size_is_the_hard_test_exactly():
    mesh, light, line, _ = ref.case_geometry("cone", 10.0)
    n = np.tile([0, 0, 1.0], (len(line), 1))
    for lt in (Light(kind="point", position=tuple(light)), Light(direction=tuple(light / np.linalg.norm(light)))):
        sm = shadow_map(mesh.vertices, mesh.faces, lt, 256)
        assert np.array_equal(light_visibility(sm, lt, line, n), sm.visibility(line, n))
        assert not np.array_equal(light_visibility(sm, lt, line, n), soft_visibility(sm, line, n, radius=0.5, tan_angle=0.05))


def test_a_lit_plane_does_not_shadow_itself():
    """Receiver-plane bias: a big kernel on a tilted plane with no occluder stays fully lit."""
    import trimesh

    plane = trimesh.Trimesh([[-4, -4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    lt = Light(kind="point", position=(-3.0, 0.0, 2.0))
    sm = shadow_map(plane.vertices, plane.faces, lt, 512)
    pts = np.stack([np.linspace(-3, 3, 50), np.zeros(50), np.zeros(50)], 1)
    vis = soft_visibility(sm, pts, np.tile([0, 0, 1.0], (50, 1)), radius=1.5)
    assert np.all(vis == 1.0)


def test_light_size_leaves_unsized_lights_bytes_alone():
    """A light keeps its serialised form (bytes, digests) unless it has a size."""
    assert Light().model_dump_json() == ('{"kind":"directional","direction":[0.0,0.0,-1.0],"position":[0.0,0.0,0.0],'
                                         '"color":[1.0,1.0,1.0],"intensity":1.0,"ambient":[0.0,0.0,0.0]}')
    sized = Light(kind="point", radius_m=0.2)
    assert sized.model_dump(mode="json")["radius_m"] == 0.2
    assert Light.model_validate(sized.model_dump(mode="json")) == sized
    assert sized.in_world_units(0.5).radius_m == pytest.approx(0.4)  # metres → world units
    with pytest.raises(ValueError, match="angular_radius_deg"):
        Light(radius_m=0.1)


def test_light_size_node():
    d = LightSize(LightSize.Params(angular_radius_deg=2.0)).compute(Light())
    assert d.angular_radius_deg == 2.0 and d.has_size
    assert LightSize(LightSize.Params()).compute(Light()) == Light()
    with pytest.raises(BadInput) as e:
        LightSize(LightSize.Params(radius_m=0.1)).compute(Light())
    assert e.value.port == "radius_m"
    with pytest.raises(BadInput) as e:
        LightSize(LightSize.Params(angular_radius_deg=1.0)).compute(Light(kind="point"))
    assert e.value.port == "angular_radius_deg"


def test_render_soft_shadows_and_size_zero_keeps_bytes():
    params, inputs = Render.examples()[0]
    p = Render.Params(**params)
    hard = Render(p).compute(**inputs)["image"].pixels
    zero = LightSize(LightSize.Params()).compute(inputs["lights"][0])
    assert np.array_equal(Render(p).compute(**{**inputs, "lights": [zero]})["image"].pixels, hard)
    soft_light = LightSize(LightSize.Params(angular_radius_deg=5.0)).compute(inputs["lights"][0])
    soft = Render(p).compute(**{**inputs, "lights": [soft_light]})["image"].pixels
    diff = np.abs(soft - hard).max(axis=2)
    assert 0 < (diff > 1e-3).mean() < 0.05  # only round the shadow's edge
    # a penumbra: pixels fully lit in the hard image only lose light, some in its shadow gain
    # light, and nothing is lit beyond the image without shadows
    open_ = Render(Render.Params(**{**params, "shadows": False})).compute(**inputs)["image"].pixels
    lit = np.all(hard == open_, axis=2)
    assert np.all(soft[lit] <= hard[lit] + 1e-6) and np.all(soft <= open_ + 1e-6)
    assert (soft[lit] < hard[lit] - 1e-3).any() and (soft[~lit] > hard[~lit] + 1e-3).any()


def test_opengl_backend_refuses_sized_lights():
    """The GL programs draw hard shadows only: a sized light is named as not drawn (the opengl
    backend then raises BackendCannotRun: numpy computes the node, or exit 2 where a graph pins
    opengl; never silently hard), and drawn with shadows off."""
    from nodes.paris.glscene import not_drawn

    params, inputs = Render.examples()[0]
    p = Render.Params(**{**params, "mouth": "skin"})
    sized = Light(angular_radius_deg=3.0)
    why = not_drawn(p, inputs["mesh"], [Light(), sized])
    assert "light 1" in why and "numpy" in why
    assert not_drawn(p.model_copy(update={"shadows": False}), inputs["mesh"], [sized]) is None
    assert not_drawn(p, inputs["mesh"], [Light()]) is None


def test_a_sphere_light_reaching_the_mesh_is_refused():
    params, inputs = Render.examples()[0]  # an ellipsoid about 1 unit (0.25 m) round z = 4 units
    near = Light(kind="point", position=(0.0, 0.0, 0.5), radius_m=0.2)  # 0.275 m from the surface
    Render(Render.Params(**params)).compute(**{**inputs, "lights": [near]})
    with pytest.raises(BadInput) as e:
        Render(Render.Params(**params)).compute(**{**inputs, "lights": [near.model_copy(update={"radius_m": 0.3})]})
    assert e.value.port == "lights" and "reaches the mesh" in e.value.message
