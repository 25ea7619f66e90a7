"""How precisely can a mirror ball's outline be located, given where it is? (issue 26 item 7)

    .venv/bin/python benchmarks/bench_paris_rim_fit.py [--half tune|check|both] [--cache DIR] [--offset PX]

On the varied probes (nodes/paris/data/varied_probes.py; ``--cache`` as in
bench_paris_probes.py) this measures, per probe, two ways of locating the outline near the
TRUE circle (make_probes.truth), and how far each moves the flash's direction (the mean
reflected direction over the largest clipped blob, as ProbeLight takes it) from the one the
true circle gives:

* **ray peaks**: 720 rays from the true centre; on each, the peak of |∂I/∂r| (image smoothed
  with σ 0.7 px, cubic interpolation, 0.1 px steps) within ±3 px of the true radius; the cone
  (or circle) through all of them by least squares (ballfind._fit).
* **image fit**: the outline's parameters (cx, cy, r) fitted to the pixels within ±3 px of it:
  per 10° sector a linear profile on each side and a step between them, box-filtered by the
  pixel (its width |cos φ| + |sin φ| across the edge); the sides' four numbers per sector are
  solved linearly for each trial outline (variable projection) and scipy's least_squares moves
  the outline; the pixel window is re-centred until the outline stops moving.  Run from the
  true circle and from a start ``--offset`` px off (centre and radius), which shows its basin.

It also prints the median over sectors of the step's log-likelihood ratio at the true outline
(0.5·n·ln(SSE without step / with step), per 10° sector): how visible the silhouette is.
This is a measurement of what a finder could reach, not the finder: find_ball does not use it.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

N_SEC = 36       # sectors of the image fit (10°)
HALF_PX = 3.0    # the window each side of the outline


def _geometry(c, xs, ys, w, h, fov):
    """Signed distance (px) of pixel centres from the outline c = (cx, cy, r), their sector,
    and a box pixel's width across the edge there."""
    from nodes.paris.ballfind import _residual

    s = _residual(xs, ys, c, w, h, fov)
    phi = np.arctan2(ys - c[1], xs - c[0])
    k = ((phi + np.pi) / (2 * np.pi) * N_SEC).astype(int) % N_SEC
    return s, k, np.abs(np.cos(phi)) + np.abs(np.sin(phi))


def _design(s, width, step=True):
    """Columns of the sector model: a step between two linear sides (or one line)."""
    if not step:
        return np.stack([np.ones_like(s), s], 1)
    cov = np.clip(0.5 - s / width, 0, 1)
    return np.stack([cov, cov * s, 1 - cov, (1 - cov) * s], 1)


def _sector_lsq(a, v, k, wts):
    """Per-sector weighted least squares of v on the columns a → (residuals, SSE per sector,
    weight per sector)."""
    m = a.shape[1]
    ata, atb = np.zeros((N_SEC, m, m)), np.zeros((N_SEC, m))
    for i in range(m):
        atb[:, i] = np.bincount(k, wts * a[:, i] * v, N_SEC)
        for j in range(i, m):
            ata[:, i, j] = ata[:, j, i] = np.bincount(k, wts * a[:, i] * a[:, j], N_SEC)
    ata += np.eye(m) * (1e-9 * ata.trace(axis1=1, axis2=2)[:, None, None] + 1e-12)
    sol = np.linalg.solve(ata, atb[..., None])[..., 0]
    r = v - np.einsum("ij,ij->i", a, sol[k])
    return r, np.bincount(k, wts * r * r, N_SEC), np.bincount(k, wts, N_SEC)


def _pixels(lum):
    h, w = lum.shape
    yy, xx = np.mgrid[0:h, 0:w]
    return xx.ravel() + 0.5, yy.ravel() + 0.5, lum.ravel()


def image_fit(lum, c0, fov):
    """The outline fitted to the pixels near it (see the module docstring) → (cx, cy, r)."""
    from scipy import optimize

    h, w = lum.shape
    xx, yy, vv = _pixels(lum)

    def residuals(p, xs, ys, v):
        s, k, width = _geometry(p, xs, ys, w, h, fov)
        return _sector_lsq(_design(s, width), v, k, np.ones_like(v))[0]

    c = np.array(c0, float)
    for _ in range(6):
        sel = np.abs(_geometry(c, xx, yy, w, h, fov)[0]) <= HALF_PX
        new = optimize.least_squares(residuals, c, diff_step=1e-4, args=(xx[sel], yy[sel], vv[sel])).x
        moved, c = float(np.abs(new - c).max()), new
        if moved < 0.02:
            break
    return c


def step_visibility(lum, c, fov):
    """Median over sectors of the step's log-likelihood ratio at the outline c."""
    h, w = lum.shape
    xx, yy, vv = _pixels(lum)
    s, k, width = _geometry(c, xx, yy, w, h, fov)
    win = (np.abs(s) <= HALF_PX).astype(float)
    _, e1, n = _sector_lsq(_design(s, width), vv, k, win)
    _, e0, _ = _sector_lsq(_design(s, width, False), vv, k, win)
    ok = n > 8
    return float(np.median(0.5 * n[ok] * np.log(np.maximum(e0[ok], 1e-30) / np.maximum(e1[ok], 1e-30))))


def ray_peaks_fit(lum, c, fov, n_rays=720, sigma=0.7, step=0.1):
    """The cone (circle) through the |∂I/∂r| peaks within ±HALF_PX of c on n_rays rays."""
    from scipy import ndimage

    from nodes.paris.ballfind import _fit

    h, w = lum.shape
    sm = ndimage.gaussian_filter(lum, sigma)
    ts = np.arange(c[2] - HALF_PX, c[2] + HALF_PX + 1e-9, step)
    a = np.arange(n_rays) * 2 * np.pi / n_rays
    xs, ys = c[0] + ts[None] * np.cos(a)[:, None], c[1] + ts[None] * np.sin(a)[:, None]
    prof = ndimage.map_coordinates(sm, [ys - 0.5, xs - 0.5], order=3, mode="nearest")
    t = ts[np.argmax(np.abs(np.gradient(prof, step, axis=1)), 1)]
    return np.array(_fit(c[0] + t * np.cos(a), c[1] + t * np.sin(a), w, h, fov))


def _direction(img, c, fov):
    from nodes.paris.probe import _largest_component, reflected_directions

    h, w = img.shape[:2]
    ys, xs = np.nonzero(_largest_component(img.max(-1) >= 0.98 * float(img.max())))
    d = reflected_directions(xs + 0.5, ys + 0.5, *c, w, h, fov).mean(0)
    return d / np.linalg.norm(d)


def row(spec, img, offset):
    from bench_paris_probes import _angle
    from nodes.paris.ballfind import luminance
    from nodes.paris.data.make_probes import truth

    t = truth(spec)
    lum = luminance(img)
    tc = np.array([t["centre_x"], t["centre_y"], t["radius"]])
    d0 = _direction(img, tc, spec.fov_deg)
    t0 = time.process_time()
    fits = [ray_peaks_fit(lum, tc, spec.fov_deg), image_fit(lum, tc, spec.fov_deg),
            image_fit(lum, tc + offset * np.array([0.8, -0.6, 0.5]), spec.fov_deg)]
    cpu = (time.process_time() - t0) / 3
    cells = [f"{np.hypot(*(f[:2] - tc[:2])):.2f} / {_angle(_direction(img, f, spec.fov_deg), d0):.2f}" for f in fits]
    return (f"| {spec.name} | {tc[2]:.1f} | {step_visibility(lum, tc, spec.fov_deg):.1f} | " + " | ".join(cells)
            + f" | {cpu:.2f} |")


def main(argv=None):
    from bench_paris_probes import probe_image
    from nodes.paris.data.varied_probes import varied

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half", default="both", choices=["tune", "check", "both"])
    ap.add_argument("--cache", default=None)
    ap.add_argument("--offset", type=float, default=2.0, help="the image fit's second start, px off")
    a = ap.parse_args(argv)
    print("centre error (px) / direction moved from the true circle's (°)\n"
          f"| probe | r (px) | step LLR (median sector) | ray peaks | image fit from the truth | "
          f"image fit from {a.offset:g} px off | CPU s per fit |\n|---|---|---|---|---|---|---|")
    for half in (["tune", "check"] if a.half == "both" else [a.half]):
        for spec in varied(half):
            print(row(spec, probe_image(spec, a.cache), a.offset), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
