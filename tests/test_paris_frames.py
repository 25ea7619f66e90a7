"""Frames, units and point lights of the Paris 2003 pipeline (issue 11).

* The same scene seen through a camera with a non-identity pose (world, mesh, probe camera and
  lights moved together) relights to the same image as with the identity pose, through every
  node that takes a camera or a light (ProbeLight → ReflectanceMap → ShininessFromSaturation →
  ShadeFace → RatioImage → FitSkinPhong → MakeLight → Render).
* A pose given the wrong way round (camera → world) is refused, with a hint.
* Point lights fall off as E = I·cos θ / d² (d in metres, a world in mm) on both Render
  backends, against the closed form per pixel; a point flash's fall-off is divided out of the
  reflectance map and does not reach the detail texture; FitSkinPhong recovers a material
  rendered under a point flash.
"""
import numpy as np
import pytest
import trimesh

from graphkit import BadInput, Camera, Image, Light, Mask
from nodes.paris.fit import FitSkinPhong
from nodes.paris.models import PhongMaterial
from nodes.paris.probe import ProbeLight, reflected_directions
from nodes.paris.ratio import RatioImage
from nodes.paris.reflectance import ReflectanceMap
from nodes.paris.render import MakeLight, Render, ShadeFace

MAT = PhongMaterial(diffuse=(0.55, 0.38, 0.29), specular=0.2, shininess=8.0)
FLASH_M = (0.0, -0.05, 0.0)  # the flash 5 cm above the lens (camera frame, metres)
FACE_M = (0.0, 0.0, 0.52)  # the face's front (camera frame, metres)
BALL_M = (0.10, 0.02, 0.6)  # the probe ball beside the face


def _head_mm():
    m = trimesh.creation.icosphere(subdivisions=4)
    m.vertices *= [80.0, 100.0, 90.0]
    m.vertices[:, 2] += 610.0
    return m


CAM = Camera(width=96, height=96, fx=300.0, fy=300.0, cx=48.0, cy=48.0, metres_per_unit=0.001)
PROBE_CAM = Camera(width=128, height=128, projection="orthographic", pixels_per_m=350.0, cx=64.0, cy=64.0,
                   metres_per_unit=0.001)


def _probe_image(cam: Camera):
    """An orthographic mirror-ball photo: the ball at BALL_M shows a 4°-wide flash halo in the
    direction of the flash from the ball, over an ambient of 0.02."""
    B = np.asarray(BALL_M)
    uv, _ = cam.project(cam.to_world(B[None] / cam.metres_per_unit))
    cx, cy = uv[0]
    r = 0.05 * cam.pixels_per_m
    yy, xx = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    d = reflected_directions(xx, yy, cx, cy, r, cam.width, cam.height, None)
    lB = np.asarray(FLASH_M) - B
    lB /= np.linalg.norm(lB)
    ang = np.degrees(np.arccos(np.clip(d @ lB, -1, 1)))
    img = 0.02 + 40.0 * np.exp(-(ang / 4.0) ** 2)
    img[(xx - cx) ** 2 + (yy - cy) ** 2 > r * r] = 0.0
    return Image(np.repeat(img[..., None], 3, 2).astype(np.float32)), (float(cx), float(cy), float(r))


def _moved(T: np.ndarray, mesh, cams):
    """The same scene in a world moved by T (4×4, world units): mesh and cameras."""
    m = mesh.copy()
    m.apply_transform(T)
    out = [c.model_copy(update={"world_to_camera": (c.pose @ np.linalg.inv(T)).tolist()}) for c in cams]
    return m, out


def _photo(mesh, cam):
    """The flash photo (Phong, point flash at FLASH_M with irradiance 1 at the face, ambient)."""
    d2 = float(np.sum((np.asarray(FLASH_M) - FACE_M) ** 2))
    flash = cam.light_to_world(Light(kind="point", position=FLASH_M, intensity=d2))
    amb = Light(ambient=(0.04, 0.04, 0.04))
    return Render(Render.Params(shadows=False, clamp=False, eye_highlights="off")).compute(
        mesh=mesh, camera=cam, material=MAT, lights=[flash], ambient=amb)


def _pipeline(mesh, cam, pcam, photo, probe, ball):
    cx, cy, r = ball
    light = ProbeLight(ProbeLight.Params(centre_x=cx, centre_y=cy, radius=r, flash_offset_m=FLASH_M,
                                         ball_position_m=BALL_M, face_position_m=FACE_M)).compute(
        probe=probe, camera=pcam)["light"]
    skin = photo["coverage"]
    rmap = ReflectanceMap(ReflectanceMap.Params(cluster_deg=4.0)).compute(
        image=photo["image"], mesh=mesh, camera=cam, skin=skin, light=light)
    from nodes.paris.shininess import ShininessFromSaturation

    s = float(ShininessFromSaturation().compute(reflectance=rmap["map"], light=light, camera=cam,
                                                image=photo["image"], mesh=mesh, skin=skin))
    shaded = ShadeFace().compute(mesh=mesh, camera=cam, map=rmap["map"], light=light)["image"]
    detail = RatioImage(RatioImage.Params(eps=0.01)).compute(a=photo["image"], b=shaded)
    fit = FitSkinPhong(FitSkinPhong.Params(starts=1, seed=3)).compute(
        image=photo["image"], skin=skin, mesh=mesh, camera=cam, light=light, shininess=s)
    key = MakeLight(MakeLight.Params(azimuth_deg=30.0, elevation_deg=10.0)).compute(camera=cam)
    lamp = MakeLight(MakeLight.Params(kind="point", azimuth_deg=-25.0, elevation_deg=20.0, distance_m=0.8,
                                      target_m=FACE_M, intensity=0.64, color=(1.0, 0.8, 0.6))).compute(camera=cam)
    out = Render(Render.Params(shadow_map_size=256)).compute(
        mesh=mesh, camera=cam, material=fit["material"], lights=[key, lamp], detail=detail,
        texture_camera=cam, ambient=fit["light"])
    return out["image"].pixels, fit["material"], light, s


def _pose(yaw, pitch, roll, t):
    a, b, c = np.radians([yaw, pitch, roll])
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Ry @ Rx @ Rz
    T[:3, 3] = t
    return T


def test_posed_camera_relights_like_the_identity_pose():
    mesh = _head_mm()
    probe, ball = _probe_image(PROBE_CAM)
    photo = _photo(mesh, CAM)
    a_img, a_mat, a_light, a_s = _pipeline(mesh, CAM, PROBE_CAM, photo, probe, ball)
    T = _pose(35.0, -20.0, 12.0, [300.0, -120.0, 450.0])
    mesh_b, (cam_b, pcam_b) = _moved(T, mesh, [CAM, PROBE_CAM])
    b_img, b_mat, b_light, b_s = _pipeline(mesh_b, cam_b, pcam_b, photo, probe, ball)
    # the light really is in the world frame: it moved with the world (metres)
    Tm = T.copy()
    Tm[:3, 3] *= 0.001
    np.testing.assert_allclose(b_light.position, Tm[:3, :3] @ a_light.position + Tm[:3, 3], atol=1e-9)
    np.testing.assert_allclose(b_light.direction, T[:3, :3] @ a_light.direction, atol=1e-9)
    assert b_s == pytest.approx(a_s, rel=1e-6)
    np.testing.assert_allclose(b_mat.diffuse, a_mat.diffuse, rtol=1e-5)
    diff = np.abs(b_img - a_img)
    print(f"\nposed vs identity: max |diff| {diff.max():.2g}, {np.mean(diff > 1e-4):.3%} of values > 1e-4")
    assert diff.max() < 1e-5  # equal up to float rounding (shadow maps laid out along the camera)
    assert a_img.max() > 0.2  # not vacuous
    # a probe camera from the other world (a frame mix-up) changes the result: the test sees frames
    c_img, *_ = _pipeline(mesh_b, cam_b, PROBE_CAM, photo, probe, ball)
    assert np.abs(c_img - a_img).max() > 0.05


def test_inverted_pose_is_refused():
    mesh = _head_mm()
    T = _pose(35.0, -20.0, 12.0, [300.0, -120.0, 450.0])
    mesh_b, (cam_b,) = _moved(T, mesh, [CAM])
    wrong = cam_b.model_copy(update={"world_to_camera": np.linalg.inv(cam_b.pose).tolist()})
    for node, kw in ((ShadeFace(), {"map": Image(np.ones((180, 360, 3), np.float32))}),
                     (Render(), {"material": MAT, "lights": [Light()]})):
        with pytest.raises(BadInput, match="camera → world") as e:
            node.compute(mesh=mesh_b, camera=wrong, **kw)
        assert e.value.port == "mesh"


# ----------------------------------------------------------------------------------------------
# point lights against the closed form


def _plane_mm(z=500.0, half=300.0):
    return trimesh.Trimesh([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]],
                           [[0, 2, 1], [0, 3, 2]], process=False)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_point_light_falls_off_as_inverse_square(projection):
    """E = I cos θ / d² per pixel, d in metres (the world is in mm), numpy and opengl."""
    from graphkit.registry import default_registry

    if projection == "perspective":
        cam = Camera(width=80, height=64, fx=70.0, fy=70.0, cx=40.0, cy=32.0, metres_per_unit=0.001)
    else:
        cam = Camera(width=80, height=64, projection="orthographic", pixels_per_m=150.0, cx=40.0, cy=32.0,
                     metres_per_unit=0.001)
    mat = PhongMaterial(diffuse=(0.5, 0.4, 0.3), specular=0.0, shininess=10.0)
    L = np.array([0.12, -0.06, 0.2])  # metres
    light = Light(kind="point", position=tuple(L), intensity=0.09, color=(1.0, 0.9, 0.8))
    yy, xx = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    o, d = cam.rays(np.stack([xx.ravel(), yy.ravel()], 1))
    t = (500.0 - o[:, 2]) / d[:, 2]
    P = (o + d * t[:, None]) * 0.001  # metres
    v = L - P
    dist = np.linalg.norm(v, axis=1)
    cos = v[:, 2] * -1 / dist  # the plane's normal faces the camera (−z)
    E = 0.09 * cos / dist ** 2
    ref = (np.asarray(mat.diffuse) * np.array([1.0, 0.9, 0.8]) * E[:, None]).reshape(cam.height, cam.width, 3)
    reg = default_registry()
    for cls in (Render, reg.backend_class("Render", "opengl")):
        out = cls(Render.Params(shadows=False, clamp=False)).compute(
            mesh=_plane_mm(), camera=cam, material=mat, lights=[light])["image"].pixels
        np.testing.assert_allclose(out, ref, rtol=2e-4, atol=1e-6)
    assert ref.max() / ref.min() > 1.5  # the fall-off is strong across the image


def _ball_mm():
    m = trimesh.creation.icosphere(subdivisions=5, radius=90.0)
    m.apply_translation([0, 0, 450.0])
    return m


def test_point_flash_falloff_stays_out_of_the_detail_texture():
    """Two equal balls at 0.35 and 0.6 m (the same normals at different distances), in a photo
    whose radiance is a function of the normal times the flash's fall-off I/d²: given the flash,
    ReflectanceMap divides the fall-off out and ShadeFace multiplies it back, so the detail
    texture is flat; without it the map averages the two balls and the detail texture keeps
    their difference."""
    from nodes.paris.render import surface

    cam = Camera(width=96, height=96, fx=200.0, fy=200.0, cx=48.0, cy=48.0, metres_per_unit=0.001)
    a = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    b = a.copy()
    a.apply_translation([-45.0, 0, 350.0])
    b.apply_translation([75.0, 0, 600.0])
    m = trimesh.util.concatenate([a, b])
    flash = Light(kind="point", position=(0.0, -0.05, 0.0), intensity=0.1)
    s = surface(m, cam)
    n = cam.dir_to_camera(s.normals)
    c = np.clip(-n[:, 2], 0, 1)
    f = np.stack([0.5 * c + 0.3 * c ** 12, 0.35 * c + 0.3 * c ** 12, 0.25 * c + 0.3 * c ** 12], 1)
    d2 = np.sum((np.asarray(flash.position) - s.points * 0.001) ** 2, 1)
    img = np.zeros((96, 96, 3), np.float32)
    img[s.coverage] = f * (flash.intensity / d2)[:, None]
    photo = Image(img)
    skin = Mask(s.coverage.astype(np.float32))
    inner = s.coverage & (np.zeros((96, 96)) == 0)
    inner[s.coverage] = c > 0.3  # skip the terminator

    def detail_spread(light):
        rm = ReflectanceMap(ReflectanceMap.Params(cluster_deg=3.0, symmetry="none")).compute(
            image=photo, mesh=m, camera=cam, skin=skin, light=light)
        sh = ShadeFace().compute(mesh=m, camera=cam, map=rm["map"], light=light)["image"]
        det = RatioImage().compute(a=photo, b=sh).pixels[..., 1][inner]
        return float(np.std(det) / np.mean(det))

    fall = flash.intensity / d2
    with_light, without = detail_spread(flash), detail_spread(None)
    print(f"\nfall-off across the balls {fall.max() / fall.min():.2f}×; detail texture spread: with the "
          f"point flash {with_light:.4f}, without {without:.4f}")
    assert fall.max() / fall.min() > 2
    assert with_light < 0.01 and without > 0.2


def test_fit_recovers_a_material_under_a_point_flash():
    cam = Camera(width=96, height=96, fx=260.0, fy=260.0, cx=48.0, cy=48.0, metres_per_unit=0.001)
    m = _ball_mm()
    m.vertices *= [0.85, 1.0, 1.0]
    F = np.array([0.03, -0.05, 0.0])
    d2 = float(np.sum((F - [0, 0, 0.36]) ** 2))
    flash = Light(kind="point", position=tuple(F), intensity=d2, ambient=(0.05, 0.05, 0.05))
    photo = Render(Render.Params(shadows=False, clamp=False)).compute(mesh=m, camera=cam, material=MAT,
                                                                    lights=[flash])
    out = FitSkinPhong(FitSkinPhong.Params(starts=2, seed=1)).compute(
        image=photo["image"], skin=photo["coverage"], mesh=m, camera=cam, light=flash, shininess=MAT.shininess)
    np.testing.assert_allclose(out["material"].diffuse, MAT.diffuse, rtol=2e-3)
    assert abs(out["material"].specular - MAT.specular) < 2e-3
    np.testing.assert_allclose(out["light"].ambient, flash.ambient, rtol=1e-9)  # the probe's, kept


def test_make_light_frames_and_metres():
    pose = _pose(90.0, 0.0, 0.0, [1000.0, 0.0, 0.0])  # camera → world, mm
    cam = CAM.model_copy(update={"world_to_camera": np.linalg.inv(pose).tolist()})
    # in the camera's frame: 2 m straight ahead of the lens; in the world (metres)
    lamp = MakeLight(MakeLight.Params(kind="point", distance_m=2.0)).compute(camera=cam)
    np.testing.assert_allclose(lamp.position, pose[:3, :3] @ [0, 0, -2.0] + [1.0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(lamp.direction, pose[:3, :3] @ [0, 0, -1.0], atol=1e-12)
    world = MakeLight(MakeLight.Params(kind="point", position_m=(0.5, 0.0, 0.0))).compute()
    assert world.position == (0.5, 0.0, 0.0)
    with pytest.raises(BadInput) as e:
        MakeLight(MakeLight.Params(kind="point")).compute()
    assert e.value.port == "position_m"
    with pytest.raises(BadInput) as e:
        MakeLight(MakeLight.Params(position_m=(1.0, 0, 0))).compute()
    assert e.value.port == "position_m"


def test_light_inside_the_mesh_is_refused():
    m = _head_mm()
    inside = Light(kind="point", position=(0.0, 0.0, 0.6), intensity=1.0)  # the head's centre, m
    for cls in (Render,):
        with pytest.raises(BadInput, match="inside the mesh") as e:
            cls(Render.Params(shadows=False)).compute(mesh=m, camera=CAM, material=MAT, lights=[inside])
        assert e.value.port == "lights"
    with pytest.raises(BadInput, match="inside the mesh") as e:
        FitSkinPhong().compute(image=Image(np.zeros((96, 96, 3), np.float32)), skin=Mask(np.ones((96, 96))),
                               mesh=m, camera=CAM, light=inside, shininess=5.0)
    assert e.value.port == "light"
