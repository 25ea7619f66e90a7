"""A mirror ball marked by hand a few pixels off, snapped to its outline (the studio's probe view,
"Snap to outline": nodes.paris.probe.snap_outline) — on the varied Mitsuba probes (issue 26 item 7).

Where ProbeLight refuses to find the ball it asks a person to mark it; a circle dragged at the
photo's full view is a few pixels off, which on a 100 px ball is degrees of flash direction.
For each probe of ``--half`` at ``--scale``: a circle ``--off`` px off the true one (centre
moved that far in a random direction, radius half as far either way: seeded, the same on every
run), ProbeLight's direction with it (the hand's error) and with the snapped circle (the snap's
error; degrees against make_probes.truth, ProbeLight with the circle given in both), whether
snap_outline is sure of it and the doubt it states, and the snap's seconds.  The summary: how
many directions are within 1° by hand and snapped, how many snaps are sure and the largest error
among those.  ``--from-finder``: the probes ProbeLight refuses only, each snapped from the
circle the studio's probe view starts from after the refusal (the finder's best, not sure of it)
— the flow a user meets: open the view, press Snap — with "by hand" that circle's error.
``--big``: also the snap's seconds on one probe at 6× and 12× (5.4 and 21.7 MP).

    .venv/bin/python benchmarks/bench_paris_snap.py [--half tune|check|holdout] [--scale 3] [--off 3]
        [--n N] [--cache DIR] [--big] [--from-finder]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_paris_probes import _angle, probe_image  # noqa: E402


def _direction(img, fov_deg, c):
    """ProbeLight's flash direction with the circle c given, or its refusal."""
    from graphkit import BadInput, Image
    from nodes.paris.probe import ProbeLight

    try:
        return ProbeLight(ProbeLight.Params(fov_deg=fov_deg, centre_x=c[0], centre_y=c[1], radius=c[2])).compute(
            probe=Image(img))["light"].direction
    except BadInput as e:
        return e.message


def _err(d, truth):
    return f"exit 2 ({d[:30]})" if isinstance(d, str) else _angle(d, truth)


def finders_start(spec, img):
    """The circle the studio's probe view starts from where it is the finder's best, which it
    was not sure of (nodes.paris.studio_view.probe_start "best"), else None."""
    from graphkit import Image
    from nodes.paris.probe import ProbeLight
    from nodes.paris.studio_view import probe_start

    circle, how, _ = probe_start(ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg)), Image(img))
    return circle if how == "best" else None


def row(spec, img, off, rng, start=None) -> dict:
    from nodes.paris.data.make_probes import truth
    from nodes.paris.probe import snap_outline

    t = truth(spec)
    a = rng.uniform(0, 2 * np.pi)
    hand = (t["centre_x"] + off * np.cos(a), t["centre_y"] + off * np.sin(a), t["radius"] + rng.choice([-1, 1]) * off / 2)
    if start is not None:
        hand = start
    t0 = time.perf_counter()
    out = snap_outline(img, hand, spec.fov_deg)
    secs = time.perf_counter() - t0
    r = {"probe": spec.name, "r": t["radius"], "hand": _err(_direction(img, spec.fov_deg, hand), t["direction"]),
         "sure": out["sure"], "doubt": out["doubt_deg"], "s": secs, "why": out["reason"], "snapped": None, "ce": None}
    if out["circle"] is not None:
        c = out["circle"]
        r["ce"] = float(np.hypot(c[0] - t["centre_x"], c[1] - t["centre_y"]))
        r["snapped"] = _err(_direction(img, spec.fov_deg, c), t["direction"])
    return r


def _f(x, fmt="{:.2f}"):
    return "—" if x is None else x if isinstance(x, str) else fmt.format(x)


def main(argv=None) -> int:
    from nodes.paris.data.varied_probes import varied

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half", default="check", choices=["tune", "check", "holdout"])
    ap.add_argument("--scale", type=int, default=3)
    ap.add_argument("--off", type=float, default=3.0, help="pixels the hand's circle is off the ball's")
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--cache", default=None, help="keep the renders here (.npy) and reuse them")
    ap.add_argument("--big", action="store_true", help="also time the snap at 6× and 12× (tune probe tv40)")
    ap.add_argument("--from-finder", action="store_true",
                    help="the probes ProbeLight refuses, snapped from the circle the studio starts from (the "
                         "finder's best, not sure) instead of a hand's circle: 'by hand' is then that circle")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(1)
    print("| probe | r (px) | by hand (°) | snapped: centre err (px) | snapped (°) | sure | doubt stated (°) | s | "
          "why not sure |\n|---|---|---|---|---|---|---|---|---|")
    rows = []
    for spec in varied(a.half, **({"n": a.n} if a.n else {}), scale=a.scale):
        img = probe_image(spec, a.cache)
        start = finders_start(spec, img) if a.from_finder else None
        if a.from_finder and start is None:
            continue   # found by ProbeLight, or no circle of the finder's to start from
        rows.append(row(spec, img, a.off, rng, start))
        r = rows[-1]
        print(f"| {r['probe']} | {r['r']:.1f} | {_f(r['hand'])} | {_f(r['ce'])} | {_f(r['snapped'])} | "
              f"{'yes' if r['sure'] else 'no'} | {_f(r['doubt'])} | {r['s']:.2f} | {r['why'][:90]} |", flush=True)
    num = [r for r in rows if isinstance(r["snapped"], float)]
    hand = [r for r in rows if isinstance(r["hand"], float)]
    sure = [r for r in num if r["sure"]]
    what = "from the finder's circle where ProbeLight refuses" if a.from_finder else f"circles {a.off:g} px off"
    print(f"\n{a.half} at {a.scale}×, {what}: by hand {sum(r['hand'] <= 1 for r in hand)}/{len(rows)} "
          f"within 1° (median {np.median([r['hand'] for r in hand]):.2f}°); snapped {sum(r['snapped'] <= 1 for r in num)}"
          f"/{len(rows)} (median {np.median([r['snapped'] for r in num]):.2f}°); sure {len(sure)}/{len(rows)}, the "
          f"largest error among them {max((r['snapped'] for r in sure), default=float('nan')):.2f}°; snap median "
          f"{np.median([r['s'] for r in rows]):.2f} s")
    if a.big:
        for k in (6, 12):
            spec = next(s for s in varied("tune", n=48, scale=k) if s.name == f"tv40x{k}")
            r = row(spec, probe_image(spec, a.cache), a.off, rng)
            img_mp = spec.width * spec.height / 1e6
            print(f"{spec.name} ({spec.width}×{spec.height}, {img_mp:.1f} MP): snap {r['s']:.2f} s, centre "
                  f"{_f(r['ce'])} px off, {_f(r['snapped'])}° (by hand {_f(r['hand'])}°), sure: {r['sure']} {r['why'][:120]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
