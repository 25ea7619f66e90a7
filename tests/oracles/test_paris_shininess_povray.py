"""ShininessFromSaturation against POV-Ray: spheres with a true Phong exponent
(``finish { phong 1 phong_size N }``) under a parallel light from the camera.

* Map path: an orthographic photo; the reflectance map is built from the known sphere normals
  (each map normal looks up its pixel on the sphere), then the node recovers N through eq. (3).
* Pipeline (issue 11): a pinhole photo of the sphere far away, the sphere as a mesh, its camera
  and a skin mask → ReflectanceMap → ShininessFromSaturation with the photo connected (as in
  graphs/face_capture.yaml), with and without a highlight clipped in red only.

Issues 3 and 11 ask: exponents 5…150 within ±10%, also when the highlight clips in one channel.
"""
import shutil
import subprocess

import numpy as np
import pytest

from graphkit import BadInput, Image, Light
from nodes.paris import sphere
from nodes.paris.shininess import ShininessFromSaturation, shininess_from_angle

SIZE = 768                    # image width/height (pixels)
HALF_EXTENT = 1.1             # the orthographic view spans ±1.1 sphere radii
SKIN = (0.8, 0.5, 0.4)        # pigment (linear RGB)
FLASH = (1.0, 0.9, 0.8)       # light colour


def _povray():
    exe = shutil.which("povray")
    if exe is None:
        pytest.skip(reason="POV-Ray is not installed (Debian package 'povray'; `make sysdeps` installs it)")
    return exe


def _render(tmp_path, exponent, phong=0.4, diffuse=0.55, light=(0.0, 0.0, -1.0), gain=1.0):
    """Linear float image of the sphere (rows top→bottom, OpenCV camera frame: y down); the
    light's colour is FLASH × gain."""
    lx, ly, lz = (1000 * c for c in light)
    scene = f"""#version 3.7;
global_settings {{ assumed_gamma 1.0 }}
camera {{ orthographic location <0,0,-10> look_at <0,0,0> right x*{2 * HALF_EXTENT} up y*{2 * HALF_EXTENT} }}
light_source {{ <{lx},{-ly},{lz}> color rgb <{gain * FLASH[0]},{gain * FLASH[1]},{gain * FLASH[2]}> parallel point_at <0,0,0> }}
sphere {{ 0, 1 texture {{ pigment {{ color rgb <{SKIN[0]},{SKIN[1]},{SKIN[2]}> }}
         finish {{ ambient 0 diffuse {diffuse} phong {phong} phong_size {exponent} }} }} }}
"""
    return _run_povray(tmp_path / f"s{exponent}_{gain}", scene, SIZE)


def _run_povray(stem, scene, size):
    """Render a POV-Ray scene at size² (no anti-aliasing, linear 16-bit PNG) → H×W×3 float."""
    import OpenImageIO as oiio

    pov, out = stem.with_suffix(".pov"), stem.with_suffix(".png")
    pov.write_text(scene)
    r = subprocess.run([_povray(), f"+I{pov}", f"+O{out}", f"+W{size}", f"+H{size}", "-D", "-V", "-A",
                        "+FN16", "File_Gamma=1.0", "+WT1"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    inp = oiio.ImageInput.open(str(out))
    px = np.asarray(inp.read_image(0, 0, 0, 3, "float"))
    inp.close()
    return px


def _reflectance_map(img, res_deg):
    """Map on the Gaussian sphere (nodes.paris.sphere layout) from the known sphere normals."""
    from scipy import ndimage

    n = sphere.pixel_normals(res_deg)
    rpx = SIZE / (2 * HALF_EXTENT)
    u = SIZE / 2 + rpx * n[..., 0]
    v = SIZE / 2 + rpx * n[..., 1]
    out = np.stack([ndimage.map_coordinates(img[..., k], [v - 0.5, u - 0.5], order=1, mode="nearest")
                    for k in range(3)], -1)
    return Image(out.astype(np.float32))


def test_eq3_closed_form():
    """Eq. (3) is exactly the inflection of cos^s(2α)/cos(α) (numeric second derivative)."""
    for s in (5, 20, 150):
        a = np.linspace(1e-4, np.pi / 4 - 1e-4, 400001)
        rho = np.cos(2 * a) ** s / np.cos(a)
        d2 = np.gradient(np.gradient(rho, a), a)
        a_inf = a[np.nonzero(np.diff(np.sign(d2)))[0][0]]
        assert shininess_from_angle(a_inf) == pytest.approx(s, rel=1e-3)


@pytest.fixture(scope="session")  # kept while xdist interleaves other modules
def renders(tmp_path_factory):
    _povray()
    tmp = tmp_path_factory.mktemp("povray")
    return {n: _render(tmp, n) for n in (5, 10, 20, 40, 80, 150)}


def test_linear_output(renders):
    """The render is linear (assumed_gamma 1, File_Gamma 1): centre = diffuse·pigment + phong."""
    c = renders[20][SIZE // 2 - 2:SIZE // 2 + 2, SIZE // 2 - 2:SIZE // 2 + 2].mean((0, 1))
    np.testing.assert_allclose(c, 0.55 * np.array(SKIN) * FLASH + 0.4 * np.array(FLASH), atol=0.01)


@pytest.mark.parametrize("res_deg", [1.0, 0.25])
@pytest.mark.parametrize("exponent", [5, 10, 20, 40, 80, 150])
def test_exponent_recovered(renders, exponent, res_deg, record_property):
    """The paper's ~1° map (ReflectanceMap's default) and a finer one."""
    light = Light(direction=(0.0, 0.0, -1.0), color=tuple(np.array(FLASH) / 0.9))
    s = ShininessFromSaturation().compute(reflectance=_reflectance_map(renders[exponent], res_deg), light=light)
    err = s / exponent - 1
    print(f"{res_deg}° map, phong_size {exponent}: s = {s:.2f} ({100 * err:+.1f}%)")
    record_property("relative_error", err)
    assert abs(err) <= 0.10


@pytest.mark.parametrize("exponent", [10, 150])
def test_light_off_the_camera_axis(tmp_path, exponent):
    """Flash 10° off the view axis (the paper's v ≈ l approximation): the highlight moves to the
    half-vector normal; the estimate stays within ±10%."""
    t = np.radians(10)
    l = (0.6 * np.sin(t), 0.8 * np.sin(t), -np.cos(t))
    img = _render(tmp_path, exponent, light=l)
    s = ShininessFromSaturation().compute(reflectance=_reflectance_map(img, 1.0),
                                          light=Light(direction=l, color=tuple(np.array(FLASH) / 0.9)))
    print(f"light 10° off axis, phong_size {exponent}: s = {s:.2f} ({100 * (s / exponent - 1):+.1f}%)")
    assert abs(s / exponent - 1) <= 0.10


def test_bad_inputs(renders):
    node = ShininessFromSaturation()
    flat = Image(np.full((180, 360, 3), [0.4, 0.3, 0.2], np.float32))
    with pytest.raises(BadInput) as e:
        node.compute(reflectance=flat, light=Light(direction=(0.0, 0.0, -1.0)))
    assert e.value.port == "reflectance"
    with pytest.raises(BadInput) as e:
        node.compute(reflectance=Image(np.zeros((10, 10, 3), np.float32)), light=Light(direction=(0.0, 0.0, -1.0)))
    assert e.value.port == "reflectance"
    with pytest.raises(BadInput) as e:  # flash behind the face
        node.compute(reflectance=_reflectance_map(renders[20], 1.0), light=Light(direction=(0.0, 0.3, 1.0)))
    assert e.value.port == "light"


# --- through the pipeline: ReflectanceMap → ShininessFromSaturation (issue 11 item 5) -----------
PIPE_SIZE = 512
PIPE_D = 100.0                # camera → sphere centre, in sphere radii (a far pinhole)
PIPE_EXPONENTS = (5, 15, 60, 150)   # (the map-level test above: 5–150 in six steps)
RED_CLIP_GAIN = 1.4           # light × 1.4: the red channel clips at the highlight, green and blue not


def _render_pinhole(tmp_path, exponent, gain=1.0, light=(0.0, 0.0, -1.0)):
    """The sphere (radius 1, centre (0, 0, PIPE_D), OpenCV camera frame) through a pinhole at
    the origin; linear 16-bit PNG, clipped at 1 like a camera."""
    l = np.asarray(light, float) / np.linalg.norm(light)
    loc = np.array([0.0, 0.0, PIPE_D]) + 1000 * l
    fov = np.degrees(2 * np.arctan(HALF_EXTENT / PIPE_D))
    col = [gain * c for c in FLASH]
    scene = f"""#version 3.7;
global_settings {{ assumed_gamma 1.0 }}
camera {{ perspective location <0,0,0> look_at <0,0,1> right x*1 up y*1 angle {fov} }}
light_source {{ <{loc[0]},{-loc[1]},{loc[2]}> color rgb <{col[0]},{col[1]},{col[2]}> parallel point_at <0,0,{PIPE_D}> }}
sphere {{ <0,0,{PIPE_D}>, 1 texture {{ pigment {{ color rgb <{SKIN[0]},{SKIN[1]},{SKIN[2]}> }}
         finish {{ ambient 0 diffuse 0.55 phong 0.4 phong_size {exponent} }} }} }}
"""
    name = f"p{exponent}_{gain}_" + "_".join(f"{c:+.3f}" for c in l)
    return _run_povray(tmp_path / name, scene, PIPE_SIZE)


@pytest.fixture(scope="session")  # kept while xdist interleaves other modules
def scene():
    """The sphere as a mesh (icosphere, 20,480 triangles), its pinhole camera, a full skin mask."""
    import trimesh

    from graphkit import Camera, Mask

    f = PIPE_SIZE / 2 * PIPE_D / HALF_EXTENT
    cam = Camera(width=PIPE_SIZE, height=PIPE_SIZE, fx=f, fy=f, cx=PIPE_SIZE / 2, cy=PIPE_SIZE / 2)
    ico = trimesh.creation.icosphere(subdivisions=5)
    mesh = trimesh.Trimesh(np.asarray(ico.vertices) + [0, 0, PIPE_D], ico.faces, process=False)
    return {"mesh": mesh, "camera": cam, "skin": Mask(np.ones((PIPE_SIZE, PIPE_SIZE), np.float32))}


@pytest.fixture(scope="session")  # kept while xdist interleaves other modules
def pinhole_renders(tmp_path_factory):
    _povray()
    tmp = tmp_path_factory.mktemp("povray_pinhole")
    return {(n, g): _render_pinhole(tmp, n, g) for n in PIPE_EXPONENTS for g in (1.0, RED_CLIP_GAIN)}


@pytest.mark.parametrize("gain", [1.0, RED_CLIP_GAIN], ids=["unclipped", "red-clipped"])
def test_exponent_through_the_pipeline(pinhole_renders, scene, gain, record_property):
    """ReflectanceMap (defaults: 2° clusters) → ShininessFromSaturation with the photo
    connected: every exponent within ±10 %.  The map-only reading of the same map is printed
    for comparison (the paper's path; biased by the map's averaging, not asserted)."""
    from nodes.paris.reflectance import ReflectanceMap

    light = Light(direction=(0.0, 0.0, -1.0), color=tuple(np.array(FLASH) / 0.9))
    rows = []
    for n in PIPE_EXPONENTS:
        img = pinhole_renders[(n, gain)]
        ball = img.max(-1) > 0
        red = float(((img[..., 0] >= 1) & ball).sum() / ball.sum())
        other = float(((img[..., 1:] >= 1).any(-1) & ball).sum())
        if gain == 1.0:
            assert red == 0
        else:   # the setup: red clips at the highlight, green and blue nowhere
            assert red > 0 and other == 0
        photo = Image(img)
        rmap = ReflectanceMap().compute(image=photo, mesh=scene["mesh"], camera=scene["camera"], skin=scene["skin"])
        s = ShininessFromSaturation().compute(reflectance=rmap["map"], light=light, image=photo, **scene)
        try:
            s_map = ShininessFromSaturation().compute(reflectance=rmap["map"], light=light)
        except BadInput as e:
            s_map = f"exit 2 ({e.message[:40]}…)"
        rows.append((n, round(100 * red, 2), round(s, 2), round(100 * (s / n - 1), 1),
                     s_map if isinstance(s_map, str) else round(100 * (s_map / n - 1), 1)))
    print(f"\nlight gain {gain}: (true s, red-clipped % of the sphere, s, error %, map-only error %)")
    for r in rows:
        print("  ", r)
    record_property("rows", rows)
    assert all(abs(r[3]) <= 10 for r in rows), rows


@pytest.mark.parametrize("exponent", [10, 150])
def test_pipeline_light_off_axis_red_clipped(tmp_path, scene, exponent):
    """Flash 10° off the view axis (each pixel's own half-vector), red clipped: within ±10 %."""
    t = np.radians(10)
    l = (0.6 * np.sin(t), 0.8 * np.sin(t), -np.cos(t))
    img = _render_pinhole(tmp_path, exponent, RED_CLIP_GAIN, light=l)
    assert (img[..., 0] >= 1).any()
    s = ShininessFromSaturation().compute(light=Light(direction=l, color=tuple(np.array(FLASH) / 0.9)),
                                          image=Image(img), **scene)
    assert abs(s / exponent - 1) <= 0.10, s


def test_pipeline_refuses_what_clipping_hides(tmp_path, scene):
    """All three channels clipped over the highlight's core (s = 150, light × 2.5): exit 2 with
    the clipped share; the diffuse skin clipped too (light × 4): exit 2, over-exposed."""
    light = Light(direction=(0.0, 0.0, -1.0), color=tuple(np.array(FLASH) / 0.9))
    with pytest.raises(BadInput, match=r"clipped in all channels.*too little of the highlight is left.*clipped: \d+%") as e:
        ShininessFromSaturation().compute(light=light, image=Image(_render_pinhole(tmp_path, 150, 2.5)), **scene)
    assert e.value.port == "image"
    with pytest.raises(BadInput, match="over-exposed") as e:
        ShininessFromSaturation().compute(light=light, image=Image(_render_pinhole(tmp_path, 30, 4.0)), **scene)
    assert e.value.port == "image"


@pytest.mark.parametrize("exponent", [10, 150])
def test_map_with_red_clipped_flat_top(tmp_path, exponent):
    """A map sampled from the photo at its normals keeps the clipped flat top: it is found and
    modelled (red restored from green and blue), within ±10 %."""
    img = _render(tmp_path, exponent, gain=RED_CLIP_GAIN)
    assert (img[..., 0] >= 1).sum() > 100 and not (img[..., 1:] >= 1).any()
    light = Light(direction=(0.0, 0.0, -1.0), color=tuple(np.array(FLASH) / 0.9))
    s = ShininessFromSaturation().compute(reflectance=_reflectance_map(img, 1.0), light=light)
    assert abs(s / exponent - 1) <= 0.10, s


def test_photo_inputs_all_or_none(scene, renders):
    light = Light(direction=(0.0, 0.0, -1.0))
    with pytest.raises(BadInput) as e:
        ShininessFromSaturation().compute(light=light, image=Image(np.zeros((PIPE_SIZE, PIPE_SIZE, 3), np.float32)),
                                          mesh=scene["mesh"])
    assert e.value.port == "camera" and "image, mesh, camera and skin together" in e.value.message
    with pytest.raises(BadInput) as e:
        ShininessFromSaturation().compute(light=light)
    assert e.value.port == "reflectance"
