"""ProbeLight against Mitsuba 3: mirror balls (a slightly rough conductor of known reflectance,
so the flash leaves a saturated highlight and an unsaturated halo) photographed by an
orthographic (and one perspective) camera, lit by a small far emitter of known direction and
colour plus a constant environment of known radiance.  The photo is clipped at 1 like a camera.

Issue 3 asks: ≥ 10 directions, direction error ≤ 1°, ambient within 2% of the environment.
"""
import numpy as np
import pytest

from graphkit import BadInput, Image
from nodes.paris.probe import CLASS_COLOURS, ProbeLight

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 not installed (pip install mitsuba; part of .[test])")

ENV = (0.2, 0.22, 0.25)         # constant environment radiance (linear RGB)
FLASH = (1.0, 0.85, 0.7)        # emitter colour (hue)
REFL = 0.8                      # the ball's reflectance (roughconductor specular_reflectance)


def _render(ldir, size=128, spp=16, perspective_fov=None, radiance=3000.0, emitter=True):
    """The probe photo, in the OpenCV camera frame of the photo: x right, y down, z forward."""
    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    ldir = np.asarray(ldir, float) / np.linalg.norm(ldir)
    dist, ang = 1000.0, np.radians(0.5)
    if perspective_fov is None:
        sensor = {"type": "orthographic",
                  "to_world": T().look_at(origin=[0, 0, -10], target=[0, 0, 0], up=[0, -1, 0]) @ T().scale([1.25, 1.25, 1])}
    else:
        sensor = {"type": "perspective", "fov": perspective_fov, "fov_axis": "y",
                  "to_world": T().look_at(origin=[0, 0, -4], target=[0, 0, 0], up=[0, -1, 0])}
    sensor["film"] = {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                      "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "independent", "sample_count": spp}
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": sensor,
        "ball": {"type": "sphere", "radius": 1.0,
                 "bsdf": {"type": "roughconductor", "material": "none", "distribution": "beckmann",
                          "alpha": 0.02, "specular_reflectance": {"type": "rgb", "value": [REFL] * 3}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": list(ENV)}},
    }
    if emitter:
        scene["flash"] = {"type": "sphere", "center": (ldir * dist).tolist(), "radius": dist * np.tan(ang),
                          "emitter": {"type": "area",
                                      "radiance": {"type": "rgb", "value": [radiance * c for c in FLASH]}}}
    img = np.array(mi.render(mi.load_dict(scene), seed=7))
    return Image(np.clip(img, 0, 1).astype(np.float32))


def _dir(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), -np.cos(t)])  # -z: towards the camera


# (θ from the camera axis, azimuth) in degrees: 12 directions over the camera-side hemisphere
DIRECTIONS = [(0, 0), (8, 30), (15, 200), (22, 95), (30, -60), (37, 160), (45, 10), (52, -120),
              (60, 250), (67, 45), (72, 180), (78, -30)]


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_directions_ambient_hue(record_property):
    node = ProbeLight(ProbeLight.Params(ball_reflectance=REFL))   # ball found automatically
    hue = np.array(FLASH) / (np.array(FLASH) @ [0.2126, 0.7152, 0.0722])
    errs, amb_errs = [], []
    for th, ph in DIRECTIONS:
        truth = _dir(th, ph)
        out = node.compute(probe=_render(truth))
        light = out["light"]
        assert light.kind == "directional" and light.intensity == 1.0
        errs.append(_angle(light.direction, truth))
        amb_errs.append(float(np.max(np.abs(np.array(light.ambient) / ENV - 1))))
        np.testing.assert_allclose(light.color, hue, rtol=0.02)
    print("ProbeLight direction errors (deg):", np.round(errs, 2).tolist())
    print("ProbeLight ambient max relative errors:", [f"{e:.1e}" for e in amb_errs])
    record_property("direction_errors_deg", errs)
    record_property("ambient_rel_errors", amb_errs)
    assert max(errs) <= 1.0, errs
    assert max(amb_errs) <= 0.02, amb_errs


def test_perspective_camera():
    fov = 30.0
    for th, ph in [(20, 40), (45, 200), (65, -80)]:
        truth = _dir(th, ph)
        light = ProbeLight(ProbeLight.Params(ball_reflectance=REFL, fov_deg=fov)).compute(
            probe=_render(truth, perspective_fov=fov))["light"]
        err = _angle(light.direction, truth)
        print(f"perspective θ={th} φ={ph}: error {err:.2f}°")
        assert err <= 1.0
        np.testing.assert_allclose(light.ambient, ENV, rtol=0.02)


def test_classes_image():
    truth = _dir(30, 45)
    out = ProbeLight(ProbeLight.Params(ball_reflectance=REFL, centre_x=64, centre_y=64, radius=51.2)).compute(
        probe=_render(truth))
    cls = out["classes"].pixels
    assert cls.shape == (128, 128, 3)
    found = {name: np.all(np.isclose(cls, col), -1) for name, col in CLASS_COLOURS.items()}
    for name in ("saturated", "halo", "ambient", "ball", "outside"):
        assert found[name].sum() > 0, name
    # halo around the highlight, ambient ring beyond it: centroids ordered along the azimuth
    ys, xs = np.nonzero(found["saturated"])
    assert xs.mean() > 64 and ys.mean() > 64   # +x right, +y down: azimuth 45° is lower right
    assert found["saturated"].sum() < found["halo"].sum() + found["ambient"].sum()


def test_white_ball_calibration():
    """Intensity from a matte white ball (closed form: radiance = albedo·I·max(n·l, 0) + ambient)."""
    truth = _dir(25, 120)
    probe = _render(truth)
    h = w = 128
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    x, y = (xx - 64) / 51.2, (yy - 64) / 51.2
    inside = x * x + y * y < 1
    n = np.stack([x, y, -np.sqrt(np.clip(1 - x * x - y * y, 0, 1))], -1)
    albedo, intensity = 0.9, 0.62
    rad = albedo * intensity * np.clip(n @ truth, 0, None) + 0.03
    white = np.where(inside[..., None], rad[..., None] * np.array(FLASH) / 0.871, 0.05)
    light = ProbeLight(ProbeLight.Params(ball_reflectance=REFL, white_albedo=albedo)).compute(
        probe=probe, white=Image(white.astype(np.float32)))["light"]
    assert light.intensity == pytest.approx(intensity, rel=0.02)


def test_bad_probes():
    node = ProbeLight(ProbeLight.Params(ball_reflectance=REFL, centre_x=64, centre_y=64, radius=51.2))
    with pytest.raises(BadInput, match="no highlight") as e:     # no flash at all
        node.compute(probe=_render(_dir(20, 0), emitter=False, spp=4))
    assert e.value.port == "probe"
    with pytest.raises(BadInput, match="saturated") as e:        # over-exposed probe
        node.compute(probe=Image(np.clip(_render(_dir(20, 0), spp=4).pixels * 20, 0, 1)))
    assert e.value.port == "probe"
    with pytest.raises(BadInput, match="behind") as e:           # flash behind the subject
        node.compute(probe=_render(_dir(110, 30), spp=4))
    assert e.value.port == "probe"
    with pytest.raises(BadInput, match="no ball"):               # nothing round in the picture
        ProbeLight().compute(probe=Image(np.full((64, 64, 3), 0.3, np.float32)))


# --- automatic ball finding on dark-rimmed probes (issue 11 item 4) ------------------------------
# The probes are rendered by nodes/paris/data/make_probes.py (Mitsuba 3: chrome ball, dark
# backdrop, blender-data HDR environments, a flash near the lens).  TUNING probes are what
# nodes/paris/ballfind.py was developed on; this test runs only the CHECK probes.

def _probes():
    from nodes.paris.data import make_probes as mp

    import os
    if not os.path.isdir(mp.WORLD_DIR):
        pytest.skip(reason=f"{mp.WORLD_DIR} missing: Debian's blender-data (CC0 HDRs; `make sysdeps` installs it)")
    return mp


def test_ball_found_on_dark_rimmed_probes(record_property):
    """Every CHECK probe: ProbeLight without centre/radius gives the flash within 1° of the
    truth (the direction from the highlight point to the flash), or refuses (exit 2, naming the
    params, or that the ball is too small in the photo for its clipped highlight); never a wrong
    direction.  At least 12 must be found."""
    mp = _probes()
    rows, found = [], 0
    for spec in mp.CHECK:
        img = Image(mp.render(spec))
        tr = mp.truth(spec)
        try:
            light = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg)).compute(probe=img)["light"]
        except BadInput as e:
            assert e.port == "probe" and ("centre_x" in e.message and "radius" in e.message
                                          or "too small in the photo" in e.message), e.message
            rows.append((spec.name, None))
            continue
        err = _angle(light.direction, tr["direction"])
        rows.append((spec.name, err))
        found += 1
        assert err <= 1.0, (spec.name, err)
    print("automatic ProbeLight on CHECK probes (direction error, deg; None = refused):",
          [(n, None if e is None else round(e, 2)) for n, e in rows])
    record_property("direction_errors_deg", rows)
    assert found >= 12, rows


def test_ball_finder_centre_and_radius():
    """find_ball itself on two CHECK probes (perspective, orthographic): centre and radius in
    ProbeLight's convention within 0.3 px of the truth; the cast shadow and the environment's
    edge inside the ball are among the circles it weighed and rejected."""
    from nodes.paris.ballfind import find_ball

    mp = _probes()
    for name in ("c_big_courtyard", "c_ortho_sunrise"):
        spec = mp.SPECS[name]
        tr = mp.truth(spec)
        fit = find_ball(mp.render(spec), spec.fov_deg)
        assert fit.confident, fit.reason
        assert np.hypot(fit.cx - tr["centre_x"], fit.cy - tr["centre_y"]) <= 0.3, (fit.summary(), tr)
        assert abs(fit.r - tr["radius"]) <= 0.3, (fit.summary(), tr)
        smaller = [c for c in fit.candidates if c[2] < fit.r - 3 and np.hypot(c[0] - fit.cx, c[1] - fit.cy) < 3]
        assert smaller, fit.candidates   # the environment's reflection edge, concentric, inside


def test_no_ball_and_saturated_probes():
    """The same scene without the ball, and a probe exposed 30× too long: exit 2 with a message
    naming the params; never a direction."""
    import dataclasses

    mp = _probes()
    spec = mp.SPECS["c_bottomleft_city"]
    node = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg))
    with pytest.raises(BadInput, match="no ball") as e:
        node.compute(probe=Image(mp.render(dataclasses.replace(spec, ball=False, spp=4))))
    assert e.value.port == "probe" and "centre_x, centre_y and radius" in e.value.message
    img = mp.render(dataclasses.replace(spec, spp=4), clip=False)
    with pytest.raises(BadInput, match="over-exposed") as e:
        node.compute(probe=Image(np.clip(img * 30, 0, 1)))
    assert e.value.port == "probe" and "centre_x" in e.value.message
    # a photo with round things but no mirror ball
    import skimage.data

    from nodes.common.color import srgb_to_linear
    with pytest.raises(BadInput, match="no ball"):
        ProbeLight().compute(probe=Image(srgb_to_linear(skimage.data.coffee() / 255.0).astype(np.float32)))


def test_white_ball_found():
    """A matte white calibration ball (no highlight) in a photo of another size is found:
    closed-form shading on a dark background with noise."""
    from nodes.paris.ballfind import find_ball

    rng = np.random.default_rng(3)
    h, w, cx, cy, r = 180, 240, 131.3, 84.6, 47.2
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    x, y = (xx - cx) / r, (yy - cy) / r
    # anti-aliased disc: 4×4 supersampling of the coverage
    cov = np.zeros((h, w))
    for oy in (np.arange(4) + 0.5) / 4 - 0.5:
        for ox in (np.arange(4) + 0.5) / 4 - 0.5:
            cov += ((xx + ox - cx) ** 2 + (yy + oy - cy) ** 2 <= r * r) / 16.0
    n_z = np.sqrt(np.clip(1 - x * x - y * y, 0, 1))
    shade = 0.8 * np.clip(0.3 * x - 0.2 * y + 0.93 * n_z, 0, None) + 0.03
    img = cov * shade + (1 - cov) * 0.05
    img = np.clip(img + rng.normal(0, 0.004, img.shape), 0, None)
    fit = find_ball(np.repeat(img[..., None], 3, 2), None, highlight=False)
    assert fit.confident, fit.reason
    assert np.hypot(fit.cx - cx, fit.cy - cy) < 0.3 and abs(fit.r - r) < 0.3, fit.summary()
