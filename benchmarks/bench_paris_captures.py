"""Paris 2003 on the CHECK set of Mitsuba captures (nodes/paris/data/make_capture_set.py).

Renders the captures when they are not cached (``--out``, default /tmp/relightkit-captures;
~1 min each on one core, run with ``nice``), runs the pipeline on each
(nodes/paris/data/capture_check.py) and prints, per capture × relight, the PSNR on skin (lit
pixels, cast-shadow pixels, all), then ProbeLight's direction error and the fitted exponent,
colour and ambient against the truth.  Goal (issue 11): ≥ 30 dB on lit skin for every light
within 45° of the camera axis, on every capture.  Never tune on this set (see
make_capture_set's docstring).

``python benchmarks/bench_paris_captures.py [--only NAME] [--json FILE] [--reflectance k=v …]
[--light-size RADIUS_M ANGLE_DEG]`` (the last: each relight also with that size, soft shadows,
against the same references, and the hard and soft Renders on all skin against Mitsuba under
the relight as an area light of that size, rendered once and cached beside the capture).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _kv(items):
    out = {}
    for it in items or []:
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv=None) -> int:
    from nodes.paris.data import capture_check, make_capture_set as cs

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=cs.DEFAULT_OUT)
    ap.add_argument("--only", action="append")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--reflectance", nargs="*", help="ReflectanceMap params, k=v")
    ap.add_argument("--fit", nargs="*", help="FitSkinPhong params, k=v")
    ap.add_argument("--light-size", nargs=2, type=float, metavar=("RADIUS_M", "ANGLE_DEG"),
                    help="also relight with soft shadows: point relights get this radius (m), "
                         "directional ones this angular radius (degrees); the soft PSNRs are printed beside")
    a = ap.parse_args(argv)
    results, fails = {}, []
    for spec in cs.CAPTURES:
        if a.only and spec.name not in a.only:
            continue
        if spec.mesh == "facemesh":
            from graphkit.registry import default_registry

            if "FaceMesh" not in default_registry().node_names():
                print(f"{spec.name}: skipped (needs the FaceMesh node, plugin graphkit-mediapipe)")
                continue
        d = cs.make(spec, a.out, log=lambda m: print("  render", m, flush=True))
        t = time.perf_counter()
        r = capture_check.run(d, reflectance=_kv(a.reflectance), fit=_kv(a.fit), light_size=a.light_size)
        r["seconds"] = time.perf_counter() - t
        results[spec.name] = r
        m, tr = r["material"], r["truth"]
        print(f"\n{spec.name}: {spec.mesh} {spec.subdivisions if spec.mesh == 'head' else ''} "
              f"{spec.projection}, {spec.albedo} albedo, {r['skin_px']} skin px, pipeline {r['seconds']:.1f} s")
        print(f"  ProbeLight from the ball beside the face (parallax-corrected, no flash offset): direction error at the face {r['dir_err_deg']:.2f}°; flash used: {r['flash']['kind']}")
        print(f"  shininess: ShininessFromSaturation {r['shininess']:.2f}, after FitSkinPhong's search "
              f"{m['shininess']:.2f} (Beckmann α ≈ Phong {tr['s']:.2f}); map clusters {r['cluster_deg']:g}°")
        print(f"  kd {tuple(round(x, 3) for x in m['diffuse'])} "
              f"(truth {tuple(round(x, 3) for x in tr['kd'])}); i_s {m['specular']:.3f}; ambient "
              f"{tuple(round(x, 4) for x in m['ambient'])} (truth {tuple(round(x, 4) for x in tr['ambient'])})")
        soft = " | soft: lit     all    cast | area ref: hard   soft" if a.light_size else ""
        print(f"  {'light':>16} {'kind':>11} {'dist':>5} {'angle':>6} {'lit':>7} {'all':>7} {'cast':>7} cast/px{soft}")
        for name, row in r["rows"].items():
            soft = (f" | {row['soft_psnr_lit']:7.2f} {row['soft_psnr_all']:7.2f} {row['soft_psnr_cast']:7.2f}"
                    f" | {row['area_hard_psnr_all']:7.2f} {row['area_soft_psnr_all']:7.2f}" if a.light_size else "")
            print(f"  {name:>16} {row['kind']:>11} {row['distance_m'] or '':>5} {row['angle']:6.1f} "
                  f"{row['psnr_lit']:7.2f} {row['psnr_all']:7.2f} {row['psnr_cast']:7.2f} {row['cast_px']}/{row['px']}{soft}")
            if row["angle"] <= 45.0 + 1e-6 and not row["psnr_lit"] >= 30.0:
                fails.append(f"{spec.name}/{name}: {row['psnr_lit']:.2f} dB")
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))
    print("\nwithin 45°, lit skin ≥ 30 dB:", "all pass" if not fails else "FAIL " + ", ".join(fails))
    return 0


if __name__ == "__main__":
    sys.exit(main())
