"""The Paris nodes' (and the mediapipe plugin's) declared port constraints (issue 25): every one
is refused by the engine naming its port (graphkit conform), and the ports that the hand-written
checks guarded before keep declaring them."""
import pytest

from conftest import graphkit
from graphkit.conformance import check_contracts
from graphkit.registry import default_registry

#: what each node declares (port: the constraints, as ``graphkit nodes`` shows them)
DECLARED = {
    "CompositeFace": {"photo": ["3 channels"], "relit": ["3 channels", "same width and height as 'photo'"],
                      "coverage": ["same width and height as 'photo'"]},
    "FaceMesh": {"image": ["1 or 3 or 4 channels"]},
    "FitSkinPhong": {"skin": ["same width and height as 'image'"], "mesh": ["finite (no NaN or Inf)"],
                     "camera": ["same width and height as 'image'"]},
    "FrameFace": {"mesh": ["finite (no NaN or Inf)"], "image": ["same width and height as 'camera'"]},
    "MeshMask": {"mesh": ["finite (no NaN or Inf)"]},
    "ProbeLight": {"camera": ["same width and height as 'probe'"]},
    "RatioImage": {"b": ["same width and height as 'a'"]},
    "ReflectanceMap": {"mesh": ["finite (no NaN or Inf)"], "camera": ["same width and height as 'image'"],
                       "skin": ["same width and height as 'image'"]},
    "EnvironmentLights": {"image": ["finite (no NaN or Inf)", "values ≥ 0"]},
    "Render": {"mesh": ["finite (no NaN or Inf)"],
               "texture_camera": ["same width and height as 'detail'"]},
    "ShadeFace": {"mesh": ["finite (no NaN or Inf)"]},
    "ShininessFromSaturation": {"mesh": ["finite (no NaN or Inf)"], "camera": ["same width and height as 'image'"],
                                "skin": ["same width and height as 'image'"]},
    "SkinSegment": {"painted": ["same width and height as 'image'"], "face": ["same width and height as 'image'"],
                    "exclude": ["same width and height as 'image'"]},
    "SmoothMesh": {"mesh": ["finite (no NaN or Inf)"]},
}


def _nodes() -> list[str]:
    reg = default_registry()
    return [n for n in reg.node_names()
            if reg.node_class(n).__module__.startswith(("nodes.paris.", "graphkit_mediapipe."))]


def test_declarations():
    reg = default_registry()
    found = {n: {p: reg.node_class(n).in_ports[p].constraints.describe()
                 for p in reg.node_class(n).constrained_ports} for n in _nodes()}
    assert {n: d for n, d in found.items() if d} == DECLARED


def test_every_declared_constraint_is_refused_naming_its_port():
    findings = check_contracts(default_registry(), nodes=_nodes())
    assert len(findings) == sum(len(c) for d in DECLARED.values() for c in d.values())
    bad = [f"{f.node}: {f.message}" for f in findings if not (f.ok and f.checked)]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("args", [["graphkit-mediapipe"], ["--node", "SkinSegment", "--node", "SmoothMesh"]])
def test_graphkit_conform_passes(args):
    r = graphkit("conform", *args)
    assert r.returncode == 0, r.stdout + r.stderr
    assert " 0 failed, 0 not checked" in r.stdout, r.stdout


def test_shared_rgb_checks():
    """nodes.paris.checks: the colour rule that no ``channels=`` declaration says (3 or more,
    or grey too) and the finite RGB pixels, one place for ProbeLight, ShininessFromSaturation,
    SkinSegment and Render's detail texture."""
    import numpy as np

    from graphkit import BadInput, Image
    from nodes.paris.checks import check_rgb, rgb_pixels

    for n in (3, 4, 5):
        check_rgb(Image(np.ones((2, 2, n))), "image")
    check_rgb(Image(np.ones((2, 2, 1))), "image", grey=True)
    for n, grey in ((1, False), (2, False), (2, True)):
        with pytest.raises(BadInput) as e:
            check_rgb(Image(np.ones((2, 2, n))), "image", grey=grey)
        assert e.value.port == "image" and e.value.message.endswith(f"channels), got {n}")
    grey = rgb_pixels(Image(np.full((2, 3, 1), 0.25)), "probe", grey=True)
    assert grey.shape == (2, 3, 3) and grey.dtype == np.float64 and (grey == 0.25).all()
    rgba = np.ones((2, 3, 4))
    rgba[0, 0, 3] = np.nan  # alpha is not looked at
    assert rgb_pixels(Image(rgba), "image").shape == (2, 3, 3)
    rgba[1, 2, 1] = np.inf
    with pytest.raises(BadInput) as e:
        rgb_pixels(Image(rgba), "white")
    assert e.value.port == "white" and e.value.message == "the image holds 0 NaN and 1 Inf values (first at index (1, 2, 1))"


def test_shared_direction_check():
    """nodes.paris.checks.unit_direction: a zero or non-finite light direction, refused naming
    the port by MakeLight (param), Render (a light input) and ShininessFromSaturation."""
    import numpy as np
    import trimesh

    from graphkit import BadInput, Camera, Image, Light
    from nodes.paris.checks import unit_direction
    from nodes.paris.models import PhongMaterial
    from nodes.paris.render import MakeLight, Render
    from nodes.paris.shininess import ShininessFromSaturation

    assert unit_direction((0.0, 3.0, -4.0), "light").tolist() == [0.0, 0.6, -0.8]
    with pytest.raises(BadInput) as e:
        MakeLight(MakeLight.Params(direction=(0.0, 0.0, 0.0))).compute()
    assert e.value.port == "direction" and e.value.message == "the light direction (0.0, 0.0, 0.0) is zero or not finite"
    m = trimesh.creation.icosphere(subdivisions=2)
    m.apply_translation([0, 0, 4.0])
    cam = Camera(width=40, height=32, fx=60, fy=60, cx=20, cy=16)
    good = Light(direction=(0.0, 0.0, -1.0))
    with pytest.raises(BadInput) as e:
        Render().compute(mesh=m, camera=cam, material=PhongMaterial(diffuse=(0.5, 0.5, 0.5), specular=0.1, shininess=9.0),
                         lights=[good, Light(direction=(np.nan, 0.0, -1.0))])
    assert e.value.port == "lights" and e.value.message == "light 1: the direction (nan, 0.0, -1.0) is zero or not finite"
    with pytest.raises(BadInput) as e:
        ShininessFromSaturation().compute(light=Light(direction=(0.0, 0.0, 0.0)),
                                          reflectance=Image(np.ones((180, 360, 3), np.float32)))
    assert e.value.port == "light" and e.value.message == "the light direction (0.0, 0.0, 0.0) is zero or not finite"
