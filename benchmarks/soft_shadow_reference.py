"""Soft shadows against Mitsuba 3: penumbra profiles of a sphere and a cone (a nose-like shape)
over a plane, lit by a spherical area light (and one far sphere standing for a directional
light with an angular radius).

Per case, the light reaching points on a line across the shadow's edge:

* Mitsuba (``llvm_ad_rgb``): the direct irradiance from the sphere emitter through Mitsuba's
  own emitter sampling (``Scene.sample_emitter_direction``, then ``Scene.ray_test`` towards the sample;
  1024 jittered-stratified samples per point, one sample set), divided by the same without the visibility test;
* ours: ``nodes.common.shadows.soft_visibility`` on the shadow map of the light's centre
  (``nodes.common.raster.shadow_map``, 1024², as Render's default).

The 10–90 % width of each profile (from the shadow side) is compared.  TUNE cases were used to
choose the filter; CHECK cases were not looked at while choosing it.

    .venv/bin/python benchmarks/soft_shadow_reference.py            # table, both sides fresh
    .venv/bin/python benchmarks/soft_shadow_reference.py --write    # store Mitsuba's profiles

``--write`` stores Mitsuba's profiles in ``tests/data/soft_shadow_profiles.json`` (small), which
``tests/test_soft_shadows.py`` compares the numpy filter with, so the test needs no Mitsuba run.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PROFILES = ROOT / "tests" / "data" / "soft_shadow_profiles.json"
SAMPLES = 1024  # Mitsuba emitter samples per point
POINTS = 200  # points along each line
MAP_SIZE = 1024
TILT_DEG = 35.0  # the light's angle from the plane's normal (towards −x: shadows fall to +x)

#: name → (shape, light distance from the occluder's centre, light radius); the sphere has
#: radius 1 and its centre 2.5 above the plane; the cone radius 0.6, height 3, on the plane.
#: "far" stands for a directional light of angular radius atan(R / D).
TUNE = {
    "sphere_d10_r0.5": ("sphere", 10.0, 0.5),
    "sphere_d6_r1": ("sphere", 6.0, 1.0),
    "cone_d10_r0.5": ("cone", 10.0, 0.5),
}
CHECK = {
    "sphere_d14_r1.2": ("sphere", 14.0, 1.2),
    "sphere_d5_r0.4": ("sphere", 5.0, 0.4),
    "cone_d7_r1": ("cone", 7.0, 1.0),
    "cone_d12_r0.3": ("cone", 12.0, 0.3),
    "sphere_far_3deg": ("sphere", 1000.0, 1000.0 * np.tan(np.radians(3.0))),
}


def case_geometry(shape: str, dist: float):
    """(occluder + plane mesh, light centre, the line's points N×3, its parameter N) of a case."""
    import trimesh

    if shape == "sphere":
        occ = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
        centre = np.array([0.0, 0.0, 2.5])
        occ.apply_translation(centre)
    else:
        occ = trimesh.creation.cone(radius=0.6, height=3.0, sections=64)
        centre = np.array([0.0, 0.0, 1.5])
    t = np.radians(TILT_DEG)
    toward = np.array([-np.sin(t), 0.0, np.cos(t)])
    light = centre + dist * toward
    plane = trimesh.Trimesh([[-4, -5, 0], [10, -5, 0], [10, 5, 0], [-4, 5, 0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    mesh = trimesh.util.concatenate([occ, plane])
    # where the light's centre sees the occluder's centre on the plane
    hit = centre - toward * (centre[2] / toward[2]) if dist > 100 else \
        light + (centre - light) * (light[2] / (light[2] - centre[2]))
    s = np.linspace(0.0, 3.0 if shape == "sphere" else 1.6, POINTS)
    if shape == "sphere":  # along the shadow's axis, out of its far side
        line = hit + np.outer(s, [1.0, 0.0, 0.0])
    else:  # across the cone's shadow, halfway along it
        line = hit + np.outer(s, [0.0, 1.0, 0.0])
    line[:, 2] = 0.0
    return mesh, light, line, s


def mitsuba_profile(shape: str, dist: float, radius: float) -> np.ndarray:
    """Mitsuba's fraction of the sphere light's irradiance reaching each point of the line."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")  # llvm_ad_rgb aborts in LLVM codegen on this machine
    mesh, light, line, _ = case_geometry(shape, dist)
    scene = mi.load_dict({"type": "scene",
                          "occ": {"type": "ply", "filename": _ply(mesh)},
                          "light": {"type": "sphere", "center": light.tolist(), "radius": float(radius),
                                    "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}})
    k = int(np.sqrt(SAMPLES))  # jittered k×k strata of the unit square, one set for every point
    g = (np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)
         + np.random.default_rng(7).random((k * k, 2))) / k
    it = mi.Interaction3f()
    it.n = mi.Normal3f(0.0, 0.0, 1.0)
    out = np.zeros(len(line))
    for i, p in enumerate(line):
        it.p = mi.Point3f(*p)
        seen = full = 0.0
        for u in g:
            ds, spec = scene.sample_emitter_direction(it, mi.Point2f(*u), False)
            e = spec[0] * max(ds.d.z, 0.0)
            full += e
            if e > 0 and not scene.ray_test(it.spawn_ray_to(ds.p)):
                seen += e
        out[i] = seen / full
    return out


def _ply(mesh) -> str:
    """The mesh written to a temporary PLY file for Mitsuba (its path)."""
    import tempfile

    f = tempfile.NamedTemporaryFile(suffix=".ply", delete=False)
    f.close()
    mesh.export(f.name)
    return f.name


def ours_profile(shape: str, dist: float, radius: float, map_size: int = MAP_SIZE) -> np.ndarray:
    """The numpy filter's fraction of the light reaching each point of the line."""
    from graphkit import Light
    from nodes.common.raster import shadow_map
    from nodes.common.shadows import soft_visibility

    mesh, light, line, _ = case_geometry(shape, dist)
    normals = np.tile([0.0, 0.0, 1.0], (len(line), 1))
    if dist > 100:  # a directional light with an angular radius
        d = light / np.linalg.norm(light)
        sm = shadow_map(mesh.vertices, mesh.faces, Light(direction=tuple(d)), map_size)
        return soft_visibility(sm, line, normals, tan_angle=radius / dist)
    sm = shadow_map(mesh.vertices, mesh.faces, Light(kind="point", position=tuple(light)), map_size)
    return soft_visibility(sm, line, normals, radius=radius)


def width_10_90(s: np.ndarray, f: np.ndarray) -> float:
    """Distance along the line between the first crossings of 10 % and 90 % of the lit level
    (the profile's last value), from the shadow side; NaN when the line starts above 10 %."""
    f = np.asarray(f, np.float64) / max(float(f[-1]), 1e-12)
    if f[0] > 0.1:
        return float("nan")

    def cross(level):
        i = int(np.argmax(f >= level))
        return s[i - 1] + (level - f[i - 1]) / (f[i] - f[i - 1]) * (s[i] - s[i - 1])

    return float(cross(0.9) - cross(0.1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--write", action="store_true", help=f"store Mitsuba's profiles in {PROFILES.relative_to(ROOT)}")
    a = ap.parse_args(argv)
    stored = {}
    print(f"{'case':20s} {'set':5s} {'mitsuba':>8s} {'ours':>8s} {'ratio':>6s}")
    for group, cases in (("tune", TUNE), ("check", CHECK)):
        for name, (shape, dist, radius) in cases.items():
            ref = mitsuba_profile(shape, dist, radius)
            s = case_geometry(shape, dist)[3]
            mine = ours_profile(shape, dist, radius)
            wm, wo = width_10_90(s, ref), width_10_90(s, mine)
            print(f"{name:20s} {group:5s} {wm:8.4f} {wo:8.4f} {wo / wm:6.3f}")
            stored[name] = {"set": group, "shape": shape, "distance": dist, "radius": float(radius),
                            "mitsuba": [round(float(v), 4) for v in ref]}
    if a.write:
        PROFILES.write_text(json.dumps({"samples": SAMPLES, "points": POINTS, "map_size": MAP_SIZE,
                                        "tilt_deg": TILT_DEG, "cases": stored}, indent=1) + "\n")
        print(f"wrote {PROFILES.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
