"""An experiment kept for the next step on issue 26 item 7: does a contrast-invariant cue see the
mirror ball's rim where find_ball's step detector does not?

    .venv/bin/python benchmarks/bench_paris_rim_coherence.py tv00x3,tv12x3,tv05x3,tv01x3 [--cache DIR]

Names are varied_probes' (``tv``/``cv``/``hv`` + number, ``xK`` for K× the size).  The cue: the
share of gradient energy that is radial about a candidate centre, (g·u)² / (|g|² + noise), in a
band around each radius — a ball's rim, and the compressed reflection just inside it, are edges
along the circle however faint, while a backdrop's texture has every orientation.  Printed per
probe: (1) the share at 0.80–1.20 of the true radius about the true centre (it peaks at 1.00);
(2) the best circles of a search around the flash's highlight scored by the share just inside
the radius minus the share 2–6 px outside it (the image brought to 360 px; centres every 4 px
within 0.3 r of the highlight, then every 1 px around the three best), how far each is from the
truth, and what ``ballfind._subpixel`` makes of it (support, gap, residual; confident?).

Seen at stop 37 on four tune probes at 3× refused by find_ball as "no closed circular outline":
(1) the share peaks at the true radius on all four, 0.53–0.83 (the backdrop beyond 0.2–0.35),
even on tv00 whose rim the eye does not see; (2) circles 0.5–11 px from the true centre, 3–7 px
too large (search CPU 0.9–1.2 s); but from them the
sub-pixel fit stays "not closed" (support 0.07–0.51): it looks for noise-significant steps, and
the rim has none.  A fit on the cue itself is the step not taken.  Stop 38 took a related one:
``ballfind._Outline`` polishes a circle on the radial gradient summed round the outline
(benchmarks/bench_paris_outline_polish.py).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _gradients(g, px):
    import cv2

    h, w = g.shape
    s = min(1.0, px / max(h, w))
    gs = g.astype(np.float32)
    if s < 1:
        gs = cv2.resize(gs, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    gs = cv2.GaussianBlur(gs, (0, 0), 1.0)
    return s, cv2.Sobel(gs, cv2.CV_32F, 1, 0, ksize=3) / 8, cv2.Sobel(gs, cv2.CV_32F, 0, 1, ksize=3) / 8


def _shares(gx, gy, cx, cy, rs, ang, noise2=0.05):
    """(rays, radii) radial share of the gradient energy, and which samples are in the frame."""
    from scipy import ndimage

    hs, ws = gx.shape
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    xs, ys = cx + rs[None] * ca, cy + rs[None] * sa
    valid = (xs >= 0) & (xs <= ws - 1) & (ys >= 0) & (ys <= hs - 1)
    vx = ndimage.map_coordinates(gx, [ys, xs], order=1, mode="nearest")
    vy = ndimage.map_coordinates(gy, [ys, xs], order=1, mode="nearest")
    rad = vx * ca + vy * sa
    return np.where(valid, rad * rad / (vx * vx + vy * vy + noise2), 0.0), valid


def _step_score(gx, gy, cx, cy, rs, ang):
    """Per radius: the mean over rays of (the share's maximum 0–2 samples inside) − (its mean
    2–6 samples outside); 0 where under 60 % of the circle is in the frame."""
    from scipy import ndimage

    c0, valid = _shares(gx, gy, cx, cy, rs, ang)
    m3 = ndimage.maximum_filter1d(c0, 3, axis=1)
    kin = np.concatenate([m3[:, :1], m3[:, :-1]], 1)
    u5 = ndimage.uniform_filter1d(c0, 5, axis=1)
    kout = np.concatenate([u5[:, 4:], np.repeat(u5[:, -1:], 4, 1)], 1)
    k = np.where(valid, kin - kout, np.nan)
    with np.errstate(invalid="ignore"):
        return np.where(valid.mean(0) >= 0.6, np.nanmean(k, 0), 0.0)


def search(g, spot, px=360, n_rays=96, top=3):
    """The ``top`` circles (score, cx, cy, r in full-size pixels) around the highlight ``spot``."""
    s, gx, gy = _gradients(g, px)
    hs, ws = gx.shape
    sx, sy = spot[0] * s, spot[1] * s
    r_lo, r_hi = max(12 * s, 0.04 * min(hs, ws)), 0.6 * min(hs, ws)
    rs = np.arange(r_lo, r_hi, 1.0)
    ang = np.arange(n_rays) * 2 * np.pi / n_rays
    offs = np.arange(-0.3 * r_hi, 0.3 * r_hi + 1e-9, 4.0)
    coarse = []
    for dy in offs:
        for dx in offs:
            sc = np.where(np.hypot(dx, dy) <= 0.3 * rs, _step_score(gx, gy, sx + dx, sy + dy, rs, ang), 0.0)
            i = int(np.argmax(sc))
            coarse.append((float(sc[i]), sx + dx, sy + dy, float(rs[i])))
    coarse.sort(reverse=True)
    ang2 = np.arange(2 * n_rays) * np.pi / n_rays
    out = []
    for best in coarse[:top]:
        _, cx, cy, r = best
        rr = np.arange(max(r - 6, r_lo), r + 6, 0.5)
        for dy in np.arange(-4, 4.01, 1.0):
            for dx in np.arange(-4, 4.01, 1.0):
                sc = _step_score(gx, gy, cx + dx, cy + dy, rr, ang2)
                i = int(np.argmax(sc))
                if sc[i] > best[0]:
                    best = (float(sc[i]), cx + dx, cy + dy, float(rr[i]))
        out.append((best[0], best[1] / s, best[2] / s, best[3] / s))
    return out


def _spec(name):
    from nodes.paris.data.varied_probes import varied

    base, _, k = name.partition("x")
    half = {"t": "tune", "c": "check", "h": "holdout"}[base[0]]
    return next(s for s in varied(half, n=48 if half == "tune" else 24, scale=int(k or 1)) if s.name == name)


def main(argv=None):
    from bench_paris_probes import probe_image

    from nodes.paris.ballfind import _NOISE, _highlights, _subpixel, luminance, stabilise
    from nodes.paris.data.make_probes import truth

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", help="comma-separated varied probe names, e.g. tv00x3,tv12x3")
    ap.add_argument("--cache", default=None, help="keep the renders here (as bench_paris_probes.py)")
    a = ap.parse_args(argv)
    for name in a.names.split(","):
        spec = _spec(name)
        img = probe_image(spec, a.cache)
        t = truth(spec)
        lum = luminance(img)
        g = stabilise(lum)
        s, gx, gy = _gradients(g, 1e9)
        fr = np.arange(0.80, 1.2001, 0.02)
        c0, valid = _shares(gx, gy, t["centre_x"], t["centre_y"], fr * t["radius"],
                            np.arange(360) * np.pi / 180)
        prof = " ".join(f"{f:.2f}:{c0[:, i][valid[:, i]].mean():.2f}" for i, f in enumerate(fr))
        print(f"{name}: true circle ({t['centre_x']:.1f}, {t['centre_y']:.1f}, r {t['radius']:.1f}); radial share "
              f"at radius/r {prof}")
        spots = _highlights(lum)
        if not spots:
            print("   no clipped highlight to search around")
            continue
        t0 = time.process_time()
        circles = search(g, spots[0])
        cpu = time.process_time() - t0
        for sc, cx, cy, r in circles:
            f = _subpixel(lum, g, _NOISE, {"cx": cx, "cy": cy, "r": r}, spec.fov_deg)
            print(f"   score {sc:.2f}: centre {np.hypot(cx - t['centre_x'], cy - t['centre_y']):.1f} px off, radius "
                  f"{r - t['radius']:+.1f} px → sub-pixel fit {np.hypot(f.cx - t['centre_x'], f.cy - t['centre_y']):.2f} "
                  f"px off, radius {f.r - t['radius']:+.2f}; confident {f.confident}, support {f.support:.2f}, gap "
                  f"{f.max_gap_deg:.0f}°, residual {f.residual_px:.2f} px")
        print(f"   search CPU {cpu:.1f} s")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    sys.exit(main())
