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
* **coarse to fine**: the same image fit on the image blurred by σ = 2, then 1, then 0.5 px,
  then unblurred (the model's step blurred alike: a normal CDF of width √(σ² + w²/12) for a
  pixel of width w across the edge), each stage started from the last, from the truth and
  from ``--offset`` px off: whether the blur widens the basin.

And the squared error of the image fit's minimum reached from ``--offset`` px off over that of
the minimum at the true circle (same pixels: within HALF_PX + 2 px of the true outline): under 1,
a wider search for the least error would leave the true circle for it.  That search itself
(**least error near the truth**): per sector the mean squared error of the step model with its
±HALF_PX window moved out by δ (−3…3 px, 0.1 px steps), the outline moved by (dx, dy, dr) on a
0.25 px grid within ±SPAN_PX of the true circle shifting sector k by dr + dx·cos φ_k + dy·sin φ_k,
the sectors' Gaussian log-likelihoods (each its own noise) summed: where its least lies, and by
how much (log-likelihood) it beats the true circle's grid point.

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
HALF_PX = 3.0    # the window each side of the outline (plus twice the blur)
COARSE_TO_FINE = (2.0, 1.0, 0.5, 0.0)   # blurs (px) of the coarse-to-fine image fit
SPAN_PX = 2.5    # the least-error search: ± this around the true circle


def _geometry(c, xs, ys, w, h, fov):
    """Signed distance (px) of pixel centres from the outline c = (cx, cy, r), their sector,
    and a box pixel's width across the edge there."""
    from nodes.paris.ballfind import _residual

    s = _residual(xs, ys, c, w, h, fov)
    phi = np.arctan2(ys - c[1], xs - c[0])
    k = ((phi + np.pi) / (2 * np.pi) * N_SEC).astype(int) % N_SEC
    return s, k, np.abs(np.cos(phi)) + np.abs(np.sin(phi))


def _design(s, width, step=True, blur=0.0):
    """Columns of the sector model: a step between two linear sides (or one line); a box
    pixel's step, or with ``blur`` (px) a normal CDF of the box and the blur together."""
    from scipy.special import ndtr

    if not step:
        return np.stack([np.ones_like(s), s], 1)
    cov = np.clip(0.5 - s / width, 0, 1) if blur == 0 else ndtr(-s / np.sqrt(blur ** 2 + width ** 2 / 12))
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


def image_fit(lum, c0, fov, blurs=(0.0,)):
    """The outline fitted to the pixels near it (see the module docstring), on the image
    blurred by each of ``blurs`` (px) in turn → (cx, cy, r)."""
    from scipy import ndimage, optimize

    h, w = lum.shape
    c = np.array(c0, float)
    for blur in blurs:
        xx, yy, vv = _pixels(ndimage.gaussian_filter(lum, blur) if blur else lum)
        half = HALF_PX + 2 * blur

        def residuals(p, xs, ys, v):
            s, k, width = _geometry(p, xs, ys, w, h, fov)
            return _sector_lsq(_design(s, width, blur=blur), v, k, np.ones_like(v))[0]

        for _ in range(6):
            sel = np.abs(_geometry(c, xx, yy, w, h, fov)[0]) <= half
            new = optimize.least_squares(residuals, c, diff_step=1e-4, args=(xx[sel], yy[sel], vv[sel])).x
            moved, c = float(np.abs(new - c).max()), new
            if moved < 0.02:
                break
    return c


def sse_ratio(lum, c, c_true, fov):
    """Squared error of the image fit at c over that at c_true, on the pixels near c_true."""
    h, w = lum.shape
    xx, yy, vv = _pixels(lum)
    sel = np.abs(_geometry(c_true, xx, yy, w, h, fov)[0]) <= HALF_PX + 2

    def sse(p):
        s, k, width = _geometry(p, xx[sel], yy[sel], w, h, fov)
        return float(np.sum(_sector_lsq(_design(s, width), vv[sel], k, np.ones(int(sel.sum())))[0] ** 2))
    return sse(c) / sse(c_true)


def least_error_search(lum, c, fov, step=0.25):
    """The least-error outline within ±SPAN_PX of c (module docstring) → ((cx, cy, r), its
    log-likelihood over c's)."""
    h, w = lum.shape
    xx, yy, vv = _pixels(lum)
    s0, k, width = _geometry(c, xx, yy, w, h, fov)
    near = np.abs(s0) <= HALF_PX + 3.1
    s0, k, width, vv = s0[near], k[near], width[near], vv[near]
    ds = np.arange(-3.0, 3.0 + 1e-9, 0.1)
    nll = np.zeros((N_SEC, len(ds)))
    for i, d in enumerate(ds):
        sel = np.abs(s0 - d) <= HALF_PX
        _, sse, n = _sector_lsq(_design(s0[sel] - d, width[sel]), vv[sel], k[sel], np.ones(int(sel.sum())))
        nll[:, i] = 0.5 * n * np.log(np.maximum(sse / np.maximum(n, 1), 1e-30))
    phi = (np.arange(N_SEC) + 0.5) / N_SEC * 2 * np.pi - np.pi
    g = np.arange(-SPAN_PX, SPAN_PX + 1e-9, step)
    dx, dy, dr = np.meshgrid(g, g, g, indexing="ij")
    delta = dr[..., None] + dx[..., None] * np.cos(phi) + dy[..., None] * np.sin(phi)
    cost = np.stack([np.interp(delta[..., j], ds, nll[j]) for j in range(N_SEC)], -1).sum(-1)
    a, b, e = np.unravel_index(np.argmin(cost), cost.shape)
    i0 = len(g) // 2
    return np.array([c[0] + g[a], c[1] + g[b], c[2] + g[e]]), float(cost[i0, i0, i0] - cost[a, b, e])


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
    start = tc + offset * np.array([0.8, -0.6, 0.5])
    fits = [ray_peaks_fit(lum, tc, spec.fov_deg), image_fit(lum, tc, spec.fov_deg),
            image_fit(lum, start, spec.fov_deg), image_fit(lum, tc, spec.fov_deg, COARSE_TO_FINE),
            image_fit(lum, start, spec.fov_deg, COARSE_TO_FINE)]
    cpu = (time.process_time() - t0) / len(fits)
    least, llr = least_error_search(lum, tc, spec.fov_deg)
    cells = [f"{np.hypot(*(f[:2] - tc[:2])):.2f} / {_angle(_direction(img, f, spec.fov_deg), d0):.2f}" for f in fits]
    return (f"| {spec.name} | {tc[2]:.1f} | {step_visibility(lum, tc, spec.fov_deg):.1f} | " + " | ".join(cells)
            + f" | {sse_ratio(lum, fits[2], fits[1], spec.fov_deg):.3f} | {np.hypot(*(least[:2] - tc[:2])):.2f} / "
            f"{least[2] - tc[2]:+.2f} / {llr:.1f} | {cpu:.2f} |")


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
          f"image fit from {a.offset:g} px off | coarse to fine from the truth | coarse to fine from {a.offset:g} px off "
          "| SSE from off / at truth | least error near the truth: centre err / dr (px) / log-lik. over the truth "
          "| CPU s per fit |\n|---|---|---|---|---|---|---|---|---|---|---|")
    for half in (["tune", "check"] if a.half == "both" else [a.half]):
        for spec in varied(half):
            print(row(spec, probe_image(spec, a.cache), a.offset), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
