"""Per-probe table of automatic mirror-ball finding on the varied probe set (issue 26 item 7).

    .venv/bin/python benchmarks/bench_paris_probes.py [--half tune|check|holdout|both] [--cache DIR]
        [--scale K] [--n N]

Renders nodes/paris/data/varied_probes.py's probes (``--cache``: keeps the renders as .npy in
DIR and reuses them; ``--scale``: each at K× its width and height, the same scene with K× the
pixels across the ball — 3 gives 1152×864 to 1536×1152 px, as real probe photos have; ``--n``:
probes per half, default 12; ``holdout``: a third set drawn like the check half; ``--unclipped``:
rendered as HDR probes, nothing clipped), runs ProbeLight without the ball's circle (``find_ball`` inside) and
prints, per probe: the true and the found radius, the centre error, the direction error of
the flash (degrees; against make_probes.truth), or the refusal (exit 2) with its reason; then
the same with the true circle given (as a person marking the ball would), and a summary of both
per half.  CPU seconds of the finding.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def probe_image(spec, cache: str | None):
    from nodes.paris.data.make_probes import render

    # a digest of the spec, not hash(): str hashes change from one process to the next, so the
    # cache was never found again
    key = hashlib.sha1(repr(spec).encode()).hexdigest()[:10]
    path = os.path.join(cache, f"{spec.name}_{key}.npy") if cache else None
    if path and os.path.exists(path):
        return np.load(path)
    img = render(spec)
    if path:
        os.makedirs(cache, exist_ok=True)
        np.save(path, img)
    return img


def run_probe(spec, img) -> dict:
    """ProbeLight on one probe, found and given: a row of the table."""
    from graphkit import BadInput, Image
    from nodes.paris.ballfind import find_ball
    from nodes.paris.data.make_probes import truth
    from nodes.paris.probe import ProbeLight

    t = truth(spec)
    t0 = time.process_time()
    fit = find_ball(img, spec.fov_deg)
    cpu = time.process_time() - t0
    row = {"probe": spec.name, "r_true": t["radius"], "r_found": fit.r, "centre_err": float(
        np.hypot(fit.cx - t["centre_x"], fit.cy - t["centre_y"])), "confident": fit.confident, "cpu_s": cpu,
        "err_deg": None, "refused": "", "given_deg": None}
    try:
        light = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg)).compute(probe=Image(img))["light"]
        row["err_deg"] = _angle(light.direction, t["direction"])
    except BadInput as e:
        row["refused"] = e.message
    try:
        light = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg, centre_x=t["centre_x"], centre_y=t["centre_y"],
                                             radius=t["radius"])).compute(probe=Image(img))["light"]
        row["given_deg"] = _angle(light.direction, t["direction"])
    except BadInput as e:
        row["given_deg"] = f"exit 2 ({e.message[:40]})"
    return row


def _fmt(row, half):
    err = "exit 2" if row["err_deg"] is None else f"{row['err_deg']:.2f}"
    given = row["given_deg"] if isinstance(row["given_deg"], str) else f"{row['given_deg']:.2f}"
    why = row["refused"][:110]
    return (f"| {half} | {row['probe']} | {row['r_true']:.1f} | {row['r_found']:.1f} | {row['centre_err']:.2f} | "
            f"{err} | {given} | {row['cpu_s']:.2f} | {why} |")


def main(argv=None):
    from nodes.paris.data.varied_probes import varied

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half", default="both", choices=["tune", "check", "holdout", "both"])
    ap.add_argument("--cache", default=None)
    ap.add_argument("--scale", type=int, default=1,
                    help="render every probe at this many times its width and height (the ball as large a "
                         "share of the frame, more pixels across it: 3 gives 1152×864 to 1536×1152 px)")
    ap.add_argument("--n", type=int, default=None, help="probes per half (default: varied_probes.N_PER_HALF)")
    ap.add_argument("--unclipped", action="store_true",
                    help="render the probes unclipped (HDR: clip=False), the flash's highlight and the lamps' kept")
    a = ap.parse_args(argv)
    halves = ["tune", "check"] if a.half == "both" else [a.half]
    print("| half | probe | r true (px) | r found | centre err (px) | direction err, found (°) | "
          "err, true circle given (°) | find CPU s | refusal |\n|---|---|---|---|---|---|---|---|---|")
    summary = []
    for half in halves:
        rows = []
        for spec in varied(half, **({'n': a.n} if a.n else {}), scale=a.scale):
            if a.unclipped:
                spec = dataclasses.replace(spec, clip=False)
            rows.append(run_probe(spec, probe_image(spec, a.cache)))
            print(_fmt(rows[-1], half), flush=True)
        for what, key in (("found", "err_deg"), ("answered with the true circle given", "given_deg")):
            errs = [r[key] for r in rows if isinstance(r[key], float)]
            summary.append(f"{half}: {len(errs)}/{len(rows)} {what}, max error "
                           f"{max(errs) if errs else float('nan'):.2f}°, {sum(e > 1.0 for e in errs)} over 1°, "
                           f"{len(rows) - len(errs)} refused")
    print("\n".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
