"""Render / ShadeFace / FrameFace / MakeLight (Paris 2003 §3, §5) against closed forms."""
import numpy as np
import pytest
import trimesh

from graphkit import BadInput, Camera, Image, Light
from graphkit.contract import compute_checked
from nodes.paris.models import PhongMaterial
from nodes.io.cameras import LoadCameraJson
from nodes.paris.render import (FrameFace, MakeLight, MeshMask, Render, ShadeFace,
                                close_holes)

CAM = Camera(width=96, height=96, fx=160, fy=160, cx=48, cy=48)
MAT = PhongMaterial(diffuse=(0.6, 0.45, 0.3), specular=0.25, shininess=12.0)


def _sphere(sub=5, centre=(0, 0, 4.0), r=1.0):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    m.apply_translation(centre)
    return m


def _exact_sphere_normals(cam, centre=np.array([0, 0, 4.0]), r=1.0):
    """Per-pixel exact normal of the sphere hit by the ray through the pixel centre."""
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    d = np.stack([(xx + 0.5 - cam.cx) / cam.fx, (yy + 0.5 - cam.cy) / cam.fy, np.ones(xx.shape)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ centre
    disc = b ** 2 - (centre @ centre - r * r)
    hit = disc > 0
    t = b - np.sqrt(np.where(hit, disc, 0))
    X = d * t[..., None]
    return hit, (X - centre) / r, -d


def _render(mesh, lights, **params):
    params.setdefault("clamp", False)
    return Render(Render.Params(**params)).compute(mesh=mesh, camera=CAM, material=MAT, lights=lights)


def test_phong_on_a_sphere_matches_closed_form():
    ld = np.array([0.4, -0.3, -1.0])
    ld /= np.linalg.norm(ld)
    light = Light(direction=tuple(ld), ambient=(0.05, 0.05, 0.05))
    out = _render(_sphere(), [light], shadows=False)
    hit, n, v = _exact_sphere_normals(CAM)
    cov = out["coverage"].alpha > 0
    inner = hit & cov
    nl = np.clip(n @ ld, 0, None)
    r = 2 * (n @ ld)[..., None] * n - ld
    spec = np.where(nl > 0, np.clip(np.sum(r * v, -1), 0, None) ** MAT.shininess, 0)
    ref = np.asarray(MAT.diffuse) * (0.05 + nl[..., None]) + MAT.specular * spec[..., None]
    err = np.abs(out["image"].pixels - ref)[inner]
    # tessellated sphere (icosphere level 5): interpolated vertex normals ≈ exact normals
    assert np.median(err) < 2e-3 and err.max() < 0.03
    # coverage ≈ the disc of the sphere's silhouette, depth ≈ the exact hit distance along z
    assert abs(int(cov.sum()) - int(hit.sum())) < 0.02 * hit.sum()
    assert out["depth"].pixels[..., 0][~cov].max() == 0


def test_detail_texture_multiplies_and_exposure_clamps_after_it():
    rng = np.random.default_rng(1)
    detail = Image(rng.uniform(0.3, 2.0, (96, 96, 3)).astype(np.float32))
    light = Light(direction=(0, 0, -1))
    base = _render(_sphere(), [light], shadows=False)["image"].pixels
    R = Render(Render.Params(shadows=False, clamp=False))
    tex = R.compute(mesh=_sphere(), camera=CAM, material=MAT, lights=[light], detail=detail,
                    texture_camera=CAM)["image"].pixels
    cov = base.sum(-1) > 0
    np.testing.assert_allclose(tex[cov], (base * detail.pixels)[cov], rtol=1e-4, atol=1e-6)
    R2 = Render(Render.Params(shadows=False, clamp=True, exposure=2.5))
    over = R2.compute(mesh=_sphere(), camera=CAM, material=MAT, lights=[light], detail=detail,
                      texture_camera=CAM)["image"].pixels
    np.testing.assert_allclose(over[cov], np.minimum(2.5 * base * detail.pixels, 1)[cov], rtol=1e-4, atol=1e-6)
    assert (over <= 1).all() and (over[cov] == 1).any()


def test_lights_add_up():
    l1 = Light(direction=(0.6, 0, -0.8))
    l2 = Light(kind="point", position=(-3.0, -2.0, 0.0), color=(0.2, 0.5, 1.0))
    a = _render(_sphere(4), [l1], shadows=False)["image"].pixels
    b = _render(_sphere(4), [l2], shadows=False)["image"].pixels
    ab = _render(_sphere(4), [l1, l2], shadows=False)["image"].pixels
    np.testing.assert_allclose(ab, a + b, atol=1e-6)


def test_shadow_map_casts_the_occluder_shadow():
    # a floor facing the camera and a small square in front of it, light from the upper left
    floor = trimesh.Trimesh([[-3, -3, 6], [3, -3, 6], [3, 3, 6], [-3, 3, 6]], [[0, 2, 1], [0, 3, 2]])
    occ = trimesh.Trimesh([[-.5, -.5, 5], [.5, -.5, 5], [.5, .5, 5], [-.5, .5, 5]], [[0, 2, 1], [0, 3, 2]])
    m = trimesh.util.concatenate([floor, occ])
    d = np.array([-1.0, -1.0, -1.0]) / np.sqrt(3)  # the shadow is offset by (+1, +1) on the floor
    light = Light(direction=tuple(d))
    on = _render(m, [light], shadows=True)
    off = _render(m, [light], shadows=False)
    # floor point (1, 1, 6) lies in the shadow of the square's centre; (−1.5, 1, 6) does not
    for (x, y), shadowed in (((1.0, 1.0), True), ((-1.5, 1.0), False), ((1.0, -1.4), False)):
        uv, _ = CAM.project(np.array([[x, y, 6.0]]))
        u, v = uv[0]
        px = on["image"].pixels[int(v), int(u)]
        ref = off["image"].pixels[int(v), int(u)]
        if shadowed:
            assert px.max() < 1e-6 < ref.max()
        else:
            np.testing.assert_allclose(px, ref, atol=1e-6)


def test_eye_highlights_are_additive_specular():
    m = _sphere(4)
    eyes = [[-0.3, -0.2, 3.05], [0.3, -0.2, 3.05]]
    light = Light(direction=(0, 0, -1))
    R = Render(Render.Params(shadows=False, clamp=False, eyes=eyes, mm_per_unit=40.0,
                             eye_shininess=50, eye_specular=2.0))
    with_eyes = R.compute(mesh=m, camera=CAM, material=MAT, lights=[light])["image"].pixels
    without = _render(m, [light], shadows=False)["image"].pixels
    add = with_eyes - without
    assert (add >= -1e-6).all() and add.max() > 0.5
    # the brightest added pixel is near the projection of an eye centre (frontal light)
    iy, ix = np.unravel_index(np.argmax(add.sum(-1)), add.shape[:2])
    uv, _ = CAM.project(np.array(eyes))
    assert np.min(np.hypot(uv[:, 0] - ix - 0.5, uv[:, 1] - iy - 0.5)) < 4
    # grey highlight (purely specular, white light)
    assert np.allclose(add[iy, ix], add[iy, ix, 0], rtol=1e-6)
    with pytest.raises(BadInput, match="eyes"):
        Render(Render.Params(eye_highlights="on")).compute(mesh=m, camera=CAM, material=MAT, lights=[light])


@pytest.mark.parametrize("ortho", [False, True])
def test_eye_rays_are_cast_only_where_the_eyes_project(monkeypatch, ortho):
    """The cornea hits are looked for only in the box each eye's sphere projects into (a
    12-megapixel photo's eyes are a few thousand of its pixels): the same image, bit for bit,
    as rays through every pixel, with an eye half out of the frame as well."""
    from nodes.paris import render

    cam = CAM if not ortho else Camera(width=96, height=96, projection="orthographic", pixels_per_m=160.0,
                                       cx=48, cy=48, metres_per_unit=0.25)
    m = _sphere(4)
    eyes = [[-0.3, -0.2, 3.05], [0.3, -0.2, 3.05]] if not ortho else [[-0.3, -0.2, 3.05], [1.17, -0.2, 3.7]]
    light = Light(direction=(0.3, -0.2, -1))
    R = Render(Render.Params(shadows=False, clamp=False, eyes=eyes, mm_per_unit=40.0, eye_shininess=50,
                             eye_specular=2.0))
    counted = []
    real = render._sphere_pixels
    monkeypatch.setattr(render, "_sphere_pixels", lambda *a: counted.append(len(real(*a))) or real(*a))
    monkeypatch.setattr(render, "_GEOMETRY", {})
    boxed = R.compute(mesh=m, camera=cam, material=MAT, lights=[light])["image"].pixels
    assert len(counted) == 2 and max(counted) < cam.width * cam.height / 8, counted
    monkeypatch.setattr(render, "_sphere_pixels", lambda camera, c, r: np.arange(camera.width * camera.height))
    monkeypatch.setattr(render, "_GEOMETRY", {})
    every = R.compute(mesh=m, camera=cam, material=MAT, lights=[light])["image"].pixels
    assert np.array_equal(boxed, every)
    plain = Render(Render.Params(shadows=False, clamp=False)).compute(mesh=m, camera=cam, material=MAT,
                                                                       lights=[light])["image"].pixels
    assert (np.abs(boxed - plain).max(-1) > 0.05).sum() >= 5   # the eyes' highlights are there


def test_the_eye_box_holds_every_pixel_whose_ray_meets_the_sphere():
    """_sphere_pixels against rays through every pixel centre, for spheres anywhere in front of
    a perspective and an orthographic camera (half out of the frame, near the camera)."""
    from nodes.paris.render import _sphere_pixels

    ortho = Camera(width=96, height=80, projection="orthographic", pixels_per_m=160.0, cx=40, cy=44,
                   metres_per_unit=0.25)
    rng = np.random.default_rng(1)
    for cam in (CAM, ortho):
        yy, xx = np.divmod(np.arange(cam.width * cam.height), cam.width)
        o, d = cam.rays(np.stack([xx + 0.5, yy + 0.5], 1))
        for _ in range(40):
            c = np.array([rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(1.0, 6.0)])
            r = rng.uniform(0.02, 0.4)
            oc = o - c
            bq = np.sum(d * oc, 1)
            hit = (bq ** 2 - (np.sum(oc * oc, 1) - r * r) > 0) & (-bq > 0)
            box = _sphere_pixels(cam, c, r)
            assert np.isin(np.nonzero(hit)[0], box).all()
            assert len(box) <= 4 * hit.sum() + 8 * (2 * r * 160 / c[2] + 4) + 40


def test_shadeface_looks_up_the_map_by_normal():
    from nodes.paris import sphere

    # a map equal to the normal's (x, y, z) → the shaded face shows the camera-frame normals
    pn = sphere.pixel_normals(1.0)
    out = ShadeFace().compute(mesh=_sphere(), camera=CAM, map=Image(pn.astype(np.float32)))
    hit, n, _ = _exact_sphere_normals(CAM)
    cov = (out["coverage"].alpha > 0) & hit
    err = np.linalg.norm(out["image"].pixels - n, axis=-1)[cov]
    assert np.median(err) < 0.01 and np.percentile(err, 99) < 0.05


def test_close_holes_and_frame_face():
    grid = trimesh.creation.box(extents=[2, 2, 0.01])
    keep = np.ones(len(grid.faces), bool)
    # an open square plate with a hole: a 6×6 grid without the 2×2 centre
    xs = np.linspace(-1, 1, 7)
    V = np.array([[x, y, 3.0] for y in xs for x in xs])
    F = []
    for j in range(6):
        for i in range(6):
            if 2 <= i <= 3 and 2 <= j <= 3:
                continue
            a = j * 7 + i
            F += [[a, a + 1, a + 8], [a, a + 8, a + 7]]
    plate = trimesh.Trimesh(V, F, process=False)
    filled = close_holes(plate)
    assert len(filled.vertices) == len(V) + 1 and len(filled.faces) == len(F) + 8
    assert abs(filled.area - 4.0) < 1e-9 and keep.all()
    fr = FrameFace(FrameFace.Params(size=64, margin=0.0)).compute(mesh=plate, camera=CAM,
                                                                   image=Image(np.ones((96, 96, 3))))
    uv, _ = fr["camera"].project(V)
    assert abs(uv.min() - 0) < 1e-6 and abs(uv.max() - 64) < 1e-6


def test_make_light_and_camera_json(tmp_path):
    l = MakeLight(MakeLight.Params(azimuth_deg=90.0)).compute()
    np.testing.assert_allclose(l.direction, (1, 0, 0), atol=1e-12)
    l = MakeLight(MakeLight.Params(elevation_deg=90.0)).compute()
    np.testing.assert_allclose(l.direction, (0, -1, 0), atol=1e-12)
    p = tmp_path / "cam.json"
    p.write_text(CAM.model_dump_json())
    node = LoadCameraJson(LoadCameraJson.Params(path=str(p)))
    assert node.compute() == CAM
    p.write_text("{\"width\": 3}")
    with pytest.raises(BadInput, match="path"):
        node.compute()


def _load(tmp_path, doc):
    p = tmp_path / "camera.json"
    p.write_text(doc if isinstance(doc, str) else __import__("json").dumps(doc))
    return LoadCameraJson(LoadCameraJson.Params(path=str(p))).compute()


def test_camera_json_orthographic_and_one_clear_message(tmp_path):
    ortho = {"width": 64, "height": 48, "projection": "orthographic", "pixels_per_m": 250.0,
             "cx": 32.0, "cy": 24.0, "metres_per_unit": 0.001}
    cam = _load(tmp_path, ortho)
    assert cam.orthographic and cam.scale == 0.25
    uv, z = cam.project(np.array([[40.0, -20.0, 900.0]]))
    np.testing.assert_allclose(uv[0], [42.0, 19.0]) and np.testing.assert_allclose(z, [900.0])
    # camera_to_world is inverted
    M = np.eye(4)
    M[:3, 3] = [0.0, 0.0, -500.0]
    cam = _load(tmp_path, {**ortho, "camera_to_world": M.tolist()})
    np.testing.assert_allclose(cam.position, [0.0, 0.0, -500.0])
    bad = [  # (file, what the single message must name)
        ({**ortho, "pixels_per_m": None, "scale": 250.0}, "unknown field 'scale'; did you mean pixels_per_m"),
        ({k: v for k, v in ortho.items() if k != "pixels_per_m"}, "needs pixels_per_m"),
        ({**ortho, "fx": 100.0}, "fx are perspective focal lengths"),
        ({"width": 64, "height": 48, "cx": 32.0, "cy": 24.0}, "needs fx and fy"),
        ({**ortho, "world_to_camera": (np.eye(4) * 2).tolist()}, "field 'world_to_camera'"),
        ({**ortho, "width": -3}, "field 'width'"),
        ('{"width": 64,', "is not valid JSON"),
        ({**ortho, "projection": "fisheye"}, "field 'projection'"),
    ]
    for doc, expect in bad:
        with pytest.raises(BadInput) as e:
            _load(tmp_path, doc)
        msg = str(e.value)
        assert e.value.port == "path" and "camera.json" in msg and expect in msg, msg
        assert "\n" not in msg and msg.count("validation error") == 0, msg


def test_orthographic_phong_sphere_matches_closed_form():
    """Orthographic camera: every view vector is the camera's −z."""
    cam = Camera(width=96, height=96, projection="orthographic", pixels_per_m=40.0, cx=48, cy=48)
    ld = np.array([0.4, -0.3, -1.0])
    ld /= np.linalg.norm(ld)
    out = Render(Render.Params(shadows=False, clamp=False)).compute(
        mesh=_sphere(), camera=cam, material=MAT, lights=[Light(direction=tuple(ld))])
    yy, xx = np.mgrid[0:96, 0:96]
    X, Y = (xx + 0.5 - 48) / 40.0, (yy + 0.5 - 48) / 40.0
    hit = X ** 2 + Y ** 2 < 1
    n = np.stack([X, Y, -np.sqrt(np.clip(1 - X ** 2 - Y ** 2, 0, None))], -1)
    v = np.array([0.0, 0.0, -1.0])
    nl = np.clip(n @ ld, 0, None)
    r = 2 * (n @ ld)[..., None] * n - ld
    spec = np.where(nl > 0, np.clip(r @ v, 0, None) ** MAT.shininess, 0)
    ref = np.asarray(MAT.diffuse) * nl[..., None] + MAT.specular * spec[..., None]
    inner = hit & (out["coverage"].alpha > 0) & (X ** 2 + Y ** 2 < 0.9)
    err = np.abs(out["image"].pixels - ref)[inner]
    assert np.median(err) < 2e-3 and err.max() < 0.03
    # its depth is the sphere's (centre z = 4)
    np.testing.assert_allclose(out["depth"].pixels[..., 0][inner], (4 + n[..., 2])[inner], atol=2e-3)


def test_frame_face_default_keeps_the_photo_pixels():
    photo = Image(np.random.default_rng(2).random((96, 96, 3)).astype(np.float32))
    for cam in (CAM, Camera(width=96, height=96, projection="orthographic", pixels_per_m=30.0, cx=48, cy=48)):
        fr = FrameFace().compute(mesh=_sphere(4, r=0.5), camera=cam, image=photo)
        c, crop = fr["camera"], fr["image"].pixels
        assert c.projection == cam.projection and crop.shape[0] < 96
        # a whole-pixel crop: its pixels are the photo's (no resampling blur)
        ox, oy = cam.cx - c.cx, cam.cy - c.cy
        assert ox == int(ox) and oy == int(oy)
        np.testing.assert_array_equal(crop, photo.pixels[int(oy):int(oy) + crop.shape[0], int(ox):int(ox) + crop.shape[1]])


def test_mesh_mask_refuses_meshes_out_of_view():
    node = MeshMask()
    assert node.compute(mesh=_sphere(4), camera=CAM).alpha.sum() > 100
    for mesh, what in ((_sphere(4, centre=(0, 0, -4)), "behind the camera"),
                       (_sphere(4, centre=(40, 0, 4)), "beside the camera"),
                       (_sphere(4, centre=(0, 0, 0.5)), "crosses the camera's image plane")):
        with pytest.raises(BadInput, match=what) as e:
            node.compute(mesh=mesh, camera=CAM)
        assert e.value.port == "mesh"


def test_bad_inputs():
    light = Light(direction=(0, 0, -1))
    # light behind the face
    with pytest.raises(BadInput, match="behind the face") as e:
        _render(_sphere(4), [Light(direction=(0, 0, 1))], shadows=False)
    assert e.value.port == "lights"
    # declared on the ports, refused by the engine before compute: a detail texture of another
    # size than its camera (same_size_as), NaN vertices (finite); no light (by hand: an
    # environment may stand in for the lights)
    with pytest.raises(BadInput) as e:
        compute_checked(Render(), mesh=_sphere(4), camera=CAM, material=MAT, lights=[light],
                        detail=Image(np.ones((50, 40, 3))), texture_camera=CAM)
    assert e.value.port == "texture_camera"
    assert e.value.message == f"sizes differ: detail is 40×50×3, texture_camera is {CAM.width}×{CAM.height}"
    with pytest.raises(BadInput) as e:
        compute_checked(Render(), mesh=_sphere(4), camera=CAM, material=MAT, lights=[])
    assert e.value.port == "lights" and e.value.message == ("needs at least 1 connection, got 0 (or "
                                                            "connect an `environment`)")
    bad = _sphere(4)
    bad.vertices[0] = np.nan
    for node, more in ((Render(), dict(material=MAT, lights=[light])), (MeshMask(), {}),
                       (FrameFace(), {}), (ShadeFace(), dict(map=Image(np.ones((180, 360, 3)))))):
        with pytest.raises(BadInput) as e:
            compute_checked(node, mesh=bad, camera=CAM, **more)
        assert e.value.port == "mesh" and e.value.message.startswith("holds 3 NaN and 0 Inf values"), node
    with pytest.raises(BadInput) as e:  # it multiplies RGB (numpy raised a ValueError before)
        Render().compute(mesh=_sphere(4), camera=CAM, material=MAT, lights=[light],
                         detail=Image(np.ones((CAM.height, CAM.width, 2))), texture_camera=CAM)
    assert e.value.port == "detail" and e.value.message == "needs an RGB image (1 or at least 3 channels), got 2"
    with pytest.raises(BadInput) as e:  # an image not taken by the camera (same_size_as)
        compute_checked(FrameFace(), mesh=_sphere(4), camera=CAM, image=Image(np.ones((50, 40, 3))))
    assert e.value.port == "image"
    assert e.value.message == f"sizes differ: camera is {CAM.width}×{CAM.height}, image is 40×50×3"
    # mesh not in front of the camera
    with pytest.raises(BadInput, match="behind the camera") as e:
        ShadeFace().compute(mesh=_sphere(4, centre=(0, 0, -4)), camera=CAM,
                            map=Image(np.ones((180, 360, 3))))
    assert e.value.port == "mesh"
    with pytest.raises(BadInput) as e:
        ShadeFace().compute(mesh=_sphere(4), camera=CAM, map=Image(np.ones((90, 360, 3))))
    assert e.value.port == "map"
