"""Paris 2003 end to end against Mitsuba 3: capture → parameters → relight → compare.

A head mesh with a known albedo and a known diffuse + glossy material (Mitsuba blendbsdf of
diffuse and Beckmann roughconductor) is photographed by Mitsuba under a small light 6 cm above
the camera, with a mirror-ball probe under the same light (nodes/paris/data/make_capture.py).
The pipeline (ProbeLight when installed, ShininessFromSaturation when installed, ReflectanceMap,
ShadeFace, RatioImage, FitSkinPhong, Render) relights the face to new directional lights, and
each result is compared with Mitsuba's render under that light.  PSNR (peak 1) on the skin
region, per light direction; pixels in a cast shadow (found by Mitsuba ray tests) are reported
separately.  Goal: ≥ 30 dB within 45° of the camera axis.
"""
import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="the oracle renders with Mitsuba 3 (pip install mitsuba)")

from graphkit import Image, Light, Mask  # noqa: E402

SIZE = 128
SPP = 64
DEBUG = False
RMAP = {}  # ReflectanceMap params (defaults: smoothing chosen from the data)
# light directions (towards the light, camera frame: x right, y down, z forward), name, angle
LIGHTS = {
    "front": (0.0, 0.0),
    "right20": (20.0, 0.0),
    "left30": (-30.0, 0.0),
    "up30": (0.0, 30.0),
    "right45": (45.0, 0.0),
    "downleft40": (-28.0, -28.0),
    "left60": (-60.0, 0.0),
}


def _dir(az, el):
    a, e = np.radians(az), np.radians(el)
    return np.array([np.sin(a) * np.cos(e), -np.sin(e), -np.cos(a) * np.cos(e)])


def _psnr(a, b):
    mse = float(np.mean((a - b) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


@pytest.fixture(scope="module", params=["head", "facemesh"])
def run(request):
    from graphkit.registry import default_registry
    from nodes.paris.data import make_capture as mc
    from nodes.paris.fit import FitSkinPhong
    from nodes.paris.ratio import RatioImage
    from nodes.paris.reflectance import ReflectanceMap
    from nodes.paris.render import Render, ShadeFace, surface

    reg = default_registry()
    if request.param == "head":
        m, alb, skin_w = mc.head_mesh()
    else:
        if "FaceMesh" not in reg.node_names():
            pytest.skip(reason="the FaceMesh node (plugin graphkit-mediapipe) is not installed")
        m, alb, skin_w = mc.facemesh_head()
    cam = mc.camera(SIZE)
    photo = Image(mc.render_scene(m, alb, cam, [], SPP, flash=True))
    probe = Image(mc.render_scene(m, alb, cam, [], SPP, flash=True, probe=True))
    from nodes.common import raster

    r = raster.rasterize(m.vertices, m.faces, cam)
    sk = raster.interpolate(r, m.faces, skin_w) > 0.5
    # drop the silhouette ring (pixels partly covered in Mitsuba's box-filtered render)
    from scipy.ndimage import binary_erosion

    skin = Mask(binary_erosion(sk, iterations=1).astype(np.float32))
    notes = [f"mesh: {request.param}, {len(m.faces)} triangles"]
    if "ProbeLight" in reg.node_names():
        pl = reg.node_class("ProbeLight")
        # the ball (radius 60 mm at the head's place) is given: on a uniform environment it
        # is invisible apart from its highlight
        D, R = mc.DISTANCE_MM, 60.0
        params = pl.Params(centre_x=SIZE / 2, centre_y=SIZE / 2,
                           radius=cam.fx * R / np.sqrt(D * D - R * R),
                           fov_deg=float(np.degrees(2 * np.arctan(SIZE / 2 / cam.fy))))
        flash = pl(params).compute(probe=probe)["light"]
        notes.append(f"ProbeLight: direction {np.round(flash.direction, 4)} ambient {np.round(flash.ambient, 4)}")
    else:
        flash = Light(direction=tuple(mc.flash_light_direction()))
        notes.append("ProbeLight not installed: the known flash direction is used")
    rmap = ReflectanceMap(ReflectanceMap.Params(**RMAP)).compute(image=photo, mesh=m, camera=cam, skin=skin,
                                                                  light=flash)
    notes.append(f"ReflectanceMap: cluster {rmap['cluster_deg']}°")
    if "ShininessFromSaturation" in reg.node_names():
        res = reg.node_class("ShininessFromSaturation")().compute(reflectance=rmap["map"], light=flash,
                                                                  camera=cam)
        s = float(res["shininess"] if isinstance(res, dict) else res)
        notes.append(f"ShininessFromSaturation: s = {s:.1f}")
    else:
        s = mc.phong_exponent_of_beckmann()
        notes.append(f"ShininessFromSaturation not installed: s = (2/α²−2)/4 = {s:.1f}")
    shaded = ShadeFace().compute(mesh=m, camera=cam, map=rmap["map"], light=flash)["image"]
    detail = RatioImage().compute(a=photo, b=shaded)
    fit = FitSkinPhong(FitSkinPhong.Params(starts=2)).compute(
        image=photo, skin=skin, mesh=m, camera=cam, light=flash, shininess=s)
    mat, flash_fit = fit["material"], fit["light"]
    notes.append(f"material {mat}")
    surf = surface(m, cam)
    sk = skin.alpha[surf.coverage] > 0.5
    rows, dbg = {}, {}
    for name, (az, el) in LIGHTS.items():
        d = _dir(az, el)
        ref = mc.render_scene(m, alb, cam, [d], SPP, seed=100 + len(rows))
        light = Light(direction=tuple(d), ambient=flash_fit.ambient)
        out = Render(Render.Params(shadow_map_size=512)).compute(
            mesh=m, camera=cam, material=mat, lights=[light], detail=detail,
            texture_camera=cam)["image"].pixels
        if DEBUG:
            dbg[name + "_ref"], dbg[name + "_out"] = ref, out
        a = out[surf.coverage][sk]
        b = ref[surf.coverage][sk]
        cast = mc.cast_shadow_mask(m, surf.points[sk], surf.normals[sk], d)
        rows[name] = {
            "angle": float(np.degrees(np.arccos(-d[2]))),
            "psnr_lit": _psnr(a[~cast], b[~cast]),
            "psnr_all": _psnr(a, b),
            "psnr_cast": _psnr(a[cast], b[cast]) if cast.any() else float("nan"),
            "cast_px": int(cast.sum()), "px": int(len(a)),
        }
    if DEBUG:
        np.savez("/tmp/paris_debug.npz", photo=photo.pixels, shaded=shaded.pixels,
                 detail=detail.pixels, rendered=fit["rendered"].pixels, **dbg)
    return rows, notes


def test_relit_face_matches_mitsuba(run):
    rows, notes = run
    print()
    for n in notes:
        print(n)
    print(f"{'light':>11} {'angle':>6} {'PSNR lit':>9} {'PSNR all':>9} {'PSNR cast':>10} cast/px")
    for name, r in rows.items():
        print(f"{name:>11} {r['angle']:6.1f} {r['psnr_lit']:9.2f} {r['psnr_all']:9.2f} "
              f"{r['psnr_cast']:10.2f} {r['cast_px']}/{r['px']}")
    for name, r in rows.items():
        if r["angle"] <= 45.0 + 1e-6:
            assert r["psnr_lit"] >= 30.0, (name, r)
        else:  # beyond 45°: reported, checked loosely
            assert r["psnr_lit"] >= 28.0, (name, r)
