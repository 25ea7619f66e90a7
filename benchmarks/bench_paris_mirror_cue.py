"""Can a mirror ball be located by its rim reflecting the backdrop (issue 26 item 7)?  A measurement.

    .venv/bin/python benchmarks/bench_paris_mirror_cue.py [--half tune|check] [--cache DIR]

At its silhouette a mirror ball's reflected rays graze it, so there is no step at the true
outline: t px inside, the rim shows the backdrop about c·√t px outside (c set by the backdrop's
distance), a radially squeezed copy.  For a candidate ball (cx, cy, r) and a backdrop plane
facing the camera D ball radii behind the ball's centre, every pixel of the band 0 … min(6 px,
r/4) inside the outline is *predicted from the image itself*: 3×3 sub-samples, those on the
sphere traced (ProbeLight's pinhole or orthographic model) to the plane, projected back into
the photo and read there (bilinear; off the frame: its border), those off the sphere read in
place; the pixel is ρ·(mirrored part) + (the rest), ρ fitted by least squares.  The score is
the RMS of the band's residual (linear luminance).  Per probe of varied_probes.py, with the
truth of make_probes.truth (D = backdrop_gap_m / ball radius):

* ``scan``: the score along cx, cy and r through the true circle (±1.5 px, 0.25 steps) with the
  true D: where its minimum lies, and the score 1.5 px off over the score at the truth;
* ``D``: the D of least score at the true circle (grid 1.5–24) and how much the score varies;
* ``refine``: Nelder–Mead on (cx, cy, r, log D) from the truth moved by ±1 px (two draws, D
  started at 6, kept in 1.5–24): the centre and radius errors it ends at and the flash
  direction's error with that circle given to ProbeLight (and with the true circle).

The CPU seconds are per refinement.  Nothing here is used by ProbeLight.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

SUB = 3                        # sub-samples per pixel side
D_GRID = np.geomspace(1.5, 24, 13)
D_RANGE = (1.5, 24.0)


def _sample(img, u, v):
    from scipy import ndimage

    return ndimage.map_coordinates(img, [v - 0.5, u - 0.5], order=1, mode="nearest")


def _mirror_points(us, vs, cx, cy, r, D, w, h, fov):
    """(on the sphere, u, v): where the mirror at sub-samples (us, vs) sees the backdrop plane
    D ball radii behind the centre, in the photo's pixels (continuous, centres at +0.5)."""
    from nodes.paris.probe import _hit, _rays_and_centre

    if fov is None:
        x, y = (us - cx) / r, (vs - cy) / r
        on = x * x + y * y < 1
        n = np.stack([x, y, -np.sqrt(np.clip(1 - x * x - y * y, 0, None))], -1)
        d = np.array([0.0, 0.0, 1.0])
        rd = d - 2 * (n @ d)[..., None] * n
        hit = n + ((D - n[..., 2]) / np.maximum(rd[..., 2], 1e-6))[..., None] * rd
        return on, cx + r * hit[..., 0], cy + r * hit[..., 1]
    d, c = _rays_and_centre(us, vs, cx, cy, r, w, h, fov)
    b = d @ c
    on = b * b - (c @ c - 1.0) > 0
    p = _hit(d, c)
    n = p - c
    rd = d - 2 * np.sum(d * n, -1, keepdims=True) * n
    hit = p + ((c[2] + D - p[..., 2]) / np.maximum(rd[..., 2], 1e-6))[..., None] * rd
    f = 0.5 * h / np.tan(np.radians(fov) / 2)
    z = np.maximum(hit[..., 2], 1e-6)
    return on, np.clip(f * hit[..., 0] / z + w / 2, -1e6, 1e6), np.clip(f * hit[..., 1] / z + h / 2, -1e6, 1e6)


def score(lum, fov, cx, cy, r, D):
    """RMS residual of the rim band predicted from the image by the mirror (see the module)."""
    h, w = lum.shape
    band_px = min(6.0, 0.25 * r)
    x0, x1 = int(max(cx - r - 2, 0)), int(min(cx + r + 3, w))
    y0, y1 = int(max(cy - r - 2, 0)), int(min(cy + r + 3, h))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    dist = np.hypot(xx + 0.5 - cx, yy + 0.5 - cy)
    band = (dist >= r - band_px) & (dist <= r + 0.7)
    py, px = yy[band], xx[band]
    offs = (np.arange(SUB) + 0.5) / SUB
    us = (px[:, None] + np.tile(offs, SUB)[None]).astype(float)
    vs = (py[:, None] + np.repeat(offs, SUB)[None]).astype(float)
    on, um, vm = _mirror_points(us, vs, cx, cy, r, D, w, h, fov)
    mirrored = np.where(on, _sample(lum, um, vm), 0.0).mean(1)
    direct = np.where(on, 0.0, _sample(lum, us, vs)).mean(1)
    y = lum[py, px] - direct
    rho = float(mirrored @ y / max(mirrored @ mirrored, 1e-20))
    return float(np.sqrt(np.mean((y - rho * mirrored) ** 2)))


def _direction(img, fov, c):
    from graphkit import BadInput, Image
    from nodes.paris.probe import ProbeLight

    try:
        node = ProbeLight(ProbeLight.Params(fov_deg=fov, centre_x=c[0], centre_y=c[1], radius=c[2]))
        return node.compute(probe=Image(img))["light"].direction
    except BadInput:
        return None


def _refine(lum, fov, c0, D0=6.0):
    from scipy.optimize import minimize

    def f(q):
        return score(lum, fov, q[0], q[1], q[2], float(np.clip(np.exp(q[3]), *D_RANGE)))

    x0 = np.array([*c0, np.log(D0)])
    simplex = np.vstack([x0, x0 + np.diag([0.7, 0.7, 0.7, 0.7])])
    res = minimize(f, x0, method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, xatol=0.02, fatol=1e-7, maxiter=600))
    return res.x[:3], float(np.clip(np.exp(res.x[3]), *D_RANGE))


def probe_rows(spec, img) -> str:
    from benchmarks.bench_paris_probes import _angle
    from nodes.paris.ballfind import luminance
    from nodes.paris.data.make_probes import truth

    t = truth(spec)
    lum = luminance(img)
    ct = np.array([t["centre_x"], t["centre_y"], t["radius"]])
    D_true = spec.backdrop_gap_m / spec.ball_radius_m
    s0 = score(lum, spec.fov_deg, *ct, D_true)
    offs = np.arange(-1.5, 1.51, 0.25)
    scan = []
    for k in range(3):
        v = []
        for o in offs:
            c = ct.copy()
            c[k] += o
            v.append(score(lum, spec.fov_deg, *c, D_true))
        scan.append(f"{'xyr'[k]} {offs[int(np.argmin(v))]:+.2f} ({v[0] / s0:.2f}, {v[-1] / s0:.2f})")
    sd = np.array([score(lum, spec.fov_deg, *ct, D) for D in D_GRID])
    d_t = _direction(img, spec.fov_deg, ct)
    given = "exit 2" if d_t is None else f"{_angle(d_t, t['direction']):.2f}"
    rng = np.random.default_rng(5)
    ref = []
    for _ in range(2):
        c0 = ct + rng.uniform(-1, 1, 3)
        t0 = time.process_time()
        c, D = _refine(lum, spec.fov_deg, c0)
        cpu = time.process_time() - t0
        d = _direction(img, spec.fov_deg, c)
        err = "exit 2" if d is None else f"{_angle(d, t['direction']):.2f}°"
        ref.append(f"{np.hypot(*(c[:2] - ct[:2])):.2f} px, r {c[2] - ct[2]:+.2f}, D {D:.1f}: {err} ({cpu:.1f} s)")
    return (f"| {spec.name} | {ct[2]:.1f} | {D_true:.1f} | {'; '.join(scan)} | {D_GRID[int(np.argmin(sd))]:.1f} "
            f"({sd.max() / sd.min():.2f}) | {given} | {' / '.join(ref)} |")


def main(argv=None):
    from benchmarks.bench_paris_probes import probe_image
    from nodes.paris.data.varied_probes import varied

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half", default="tune", choices=["tune", "check"])
    ap.add_argument("--cache", default=None)
    ap.add_argument("--scale", type=int, default=1, help="each probe rendered at this many times its size")
    a = ap.parse_args(argv)
    print("| probe | r (px) | D true | scan, true D: argmin offset (score ±1.5 px / at truth) | D of least score "
          "(max/min) | err, true circle (°) | refine from ±1 px: centre err, r err, D: direction err (CPU) |\n"
          "|---|---|---|---|---|---|---|")
    for spec in varied(a.half, scale=a.scale):
        print(probe_rows(spec, probe_image(spec, a.cache)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
