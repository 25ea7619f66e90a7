"""Paris 2003 end to end against Mitsuba 3: capture → parameters → relight → compare.

A head mesh with a known albedo and a known diffuse + glossy material (Mitsuba blendbsdf of
diffuse and Beckmann roughconductor) is photographed by Mitsuba under a small light 6 cm above
the camera, with a mirror-ball probe under the same light (nodes/paris/data/make_capture.py:
the TUNING case).  The pipeline (ProbeLight when installed, ShininessFromSaturation when
installed, ReflectanceMap, ShadeFace, RatioImage, FitSkinPhong, Render) relights the face to new
directional lights, and each result is compared with Mitsuba's render under that light.  PSNR
(peak 1) on the skin region, per light direction; pixels in a cast shadow (found by Mitsuba ray
tests) are reported separately.  Goal: ≥ 30 dB within 45° of the camera axis.

Then one capture of the CHECK set (make_capture_set.py, never tuned on), rendered small:
perspective at 1.2 m, a point flash off the lens, the probe ball beside the face, point and
directional relights; the same goal, and ProbeLight's direction, the fitted colour and the
ambient against the scene's truth.
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
                           flash_offset_m=tuple(np.asarray(mc.FLASH_POS) / 1000.0),
                           ball_position_m=(0.0, 0.0, D / 1000.0),
                           face_position_m=(0.0, 0.0, (D - 88.0) / 1000.0))
        flash = pl(params).compute(probe=probe, camera=cam)["light"]
        notes.append(f"ProbeLight: direction {np.round(flash.direction, 4)} ambient {np.round(flash.ambient, 4)}")
    else:
        flash = Light(direction=tuple(mc.flash_light_direction()))
        notes.append("ProbeLight not installed: the known flash direction is used")
    rmap = ReflectanceMap(ReflectanceMap.Params(**RMAP)).compute(image=photo, mesh=m, camera=cam, skin=skin,
                                                                  light=flash)
    notes.append(f"ReflectanceMap: cluster {rmap['cluster_deg']}°")
    if "ShininessFromSaturation" in reg.node_names():
        res = reg.node_class("ShininessFromSaturation")().compute(reflectance=rmap["map"], light=flash,
                                                                  camera=cam, image=photo, mesh=m, skin=skin)
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


# ----------------------------------------------------------------------------------------------
# a capture of the CHECK set (nodes/paris/data/make_capture_set.py): never tuned on


@pytest.fixture(scope="module")
def check_capture(tmp_path_factory):
    """One capture of the check set, small: a 5,120-triangle head with a freckled UV texture,
    perspective at 1.2 m, the flash 5 cm off the lens (a point light), the mirror ball 20 cm
    beside the face (its own camera), relit by directional and point lights at 0.7–2 m.
    (benchmarks/bench_paris_captures.py runs all five at 160 px.)"""
    from nodes.paris.data import capture_check, make_capture_set as cs

    spec = next(s for s in cs.CAPTURES if s.name == "coarse_freckles")
    d = cs.make(spec, str(tmp_path_factory.mktemp("captures")), size=128, probe_size=320, spp=16,
                log=lambda m: None)
    return capture_check.run(d)


def test_check_capture_relights_within_45_degrees_at_30_db(check_capture):
    r = check_capture
    tr, m = r["truth"], r["material"]
    print(f"\nProbeLight (ball beside the face, parallax-corrected): direction error {r['dir_err_deg']:.2f}°")
    print(f"shininess {r['shininess']:.2f} (Beckmann ≈ Phong {tr['s']:.2f}); kd {np.round(m['diffuse'], 3)} "
          f"(truth {np.round(tr['kd'], 3)}); ambient {np.round(m['ambient'], 4)} (truth {np.round(tr['ambient'], 4)}); "
          f"map clusters {r['cluster_deg']}°")
    print(f"{'light':>16} {'angle':>6} {'PSNR lit':>9} {'PSNR all':>9}")
    for name, row in r["rows"].items():
        print(f"{name:>16} {row['angle']:6.1f} {row['psnr_lit']:9.2f} {row['psnr_all']:9.2f}")
    assert r["dir_err_deg"] <= 1.0
    np.testing.assert_allclose(m["diffuse"], tr["kd"], rtol=0.05)
    np.testing.assert_allclose(m["ambient"], tr["ambient"], rtol=0.1)
    for name, row in r["rows"].items():
        if row["angle"] <= 45.0 + 1e-6:
            assert row["psnr_lit"] >= 30.0, (name, row)
        else:
            assert row["psnr_lit"] >= 27.0, (name, row)
