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

``--bias``: what ProbeLight's bias bound (``probe.BIAS_PER_RMS`` × the outline's residual may be a
shift along a side; refused where that moves the flash by over ``MAX_BIAS_DEG``) costs and what it
saves: per probe whose ball the finder is sure of, the direction error with the bound off and the
bias the bound measured (degrees, at ``BIAS_PER_RMS``); then, per half, how many would be answered
and the largest error with the bound's factor scaled to 2.0 and 1.5 (the bias scales with the factor
to first order).

``--halo``: what the halo's refinement of a clipped highlight does (``probe.MAX_HALO_SHIFT_DEG``):
per probe, with the true circle given, how far the halo's excess-weighted mean moves the clipped
blob's direction and the direction error with the refinement always, never, and under ProbeLight
14's bound (kept up to 1°); then, per half, the largest and the mean error under that bound and now.
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


def _bias_row(img, fit, fov_deg, t) -> dict:
    """With the bias bound off: the direction error and the bias the bound measured (degrees;
    None where the finder is not sure of ``fit``, see ``--bias``)."""
    from unittest import mock

    from graphkit import BadInput, Image
    from nodes.paris import probe as pm

    out = {"bias_deg": None, "unbound_deg": None}
    if not fit.confident:
        return out
    out["bias_deg"] = pm.outline_doubt(img, fit, fov_deg)[1]
    with mock.patch.object(pm, "MAX_BIAS_DEG", np.inf):
        try:
            light = pm.ProbeLight(pm.ProbeLight.Params(fov_deg=fov_deg)).compute(probe=Image(img))["light"]
            out["unbound_deg"] = _angle(light.direction, t["direction"])
        except BadInput:
            pass
    return out


def _halo_row(spec, img, t) -> dict:
    """With the true circle given: the halo's shift of the blob's direction, the direction error
    with the refinement always (bound off), never (the blob alone) and under ProbeLight 14's 1°
    bound (see ``--halo``)."""
    from unittest import mock

    from graphkit import BadInput, Image
    from nodes.paris import probe as pm

    d = {}
    for name, bound, refine in (("refined", np.inf, True), ("blob", np.inf, False), ("old", 1.0, True)):
        try:
            with mock.patch.object(pm, "MAX_HALO_SHIFT_DEG", bound):
                d[name] = pm.ProbeLight(pm.ProbeLight.Params(
                    fov_deg=spec.fov_deg, centre_x=t["centre_x"], centre_y=t["centre_y"], radius=t["radius"],
                    refine_with_halo=refine)).compute(probe=Image(img))["light"].direction
        except BadInput:
            return {"halo_shift_deg": None, "refined_deg": None, "blob_deg": None, "old_bound_deg": None}
    return {"halo_shift_deg": _angle(d["refined"], d["blob"]), "refined_deg": _angle(d["refined"], t["direction"]),
            "blob_deg": _angle(d["blob"], t["direction"]), "old_bound_deg": _angle(d["old"], t["direction"])}


def run_probe(spec, img, bias=False, halo=False) -> dict:
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
    if halo:
        row.update(_halo_row(spec, img, t))
    if bias:
        row.update(_bias_row(img, fit, spec.fov_deg, t))
    return row


def _fmt(row, half):
    err = "exit 2" if row["err_deg"] is None else f"{row['err_deg']:.2f}"
    given = row["given_deg"] if isinstance(row["given_deg"], str) else f"{row['given_deg']:.2f}"
    why = row["refused"][:110]
    keys = [k for k in ("unbound_deg", "bias_deg", "halo_shift_deg", "refined_deg", "blob_deg", "old_bound_deg")
            if k in row]
    extra = " | ".join("—" if row[k] is None else f"{row[k]:.2f}" for k in keys) + " |" if keys else ""
    return (f"| {half} | {row['probe']} | {row['r_true']:.1f} | {row['r_found']:.1f} | {row['centre_err']:.2f} | "
            f"{err} | {given} | {row['cpu_s']:.2f} | {why} |" + (" " + extra if extra else ""))


def _halo_summary(half, rows) -> list[str]:
    """The errors, the true circle given, under ProbeLight 14's 1° bound for the halo's
    refinement and as ProbeLight is now (``--halo``)."""
    rows = [r for r in rows if r["halo_shift_deg"] is not None and isinstance(r["given_deg"], float)]
    out = []
    for what, key in (("under the old 1° bound", "old_bound_deg"), ("now", "given_deg")):
        errs = [r[key] for r in rows]
        out.append(f"{half}: the true circle given, the halo's refinement {what}: {len(errs)} answered, max error "
                   f"{max(errs, default=float('nan')):.2f}°, mean {np.mean(errs) if errs else float('nan'):.3f}°, "
                   f"{sum(e > 1.0 for e in errs)} over 1°")
    return out


def _bias_summary(half, rows) -> list[str]:
    """Answered and the largest error with the bias bound's factor scaled (``--bias``)."""
    from nodes.paris import probe as pm

    out = []
    for k in (pm.BIAS_PER_RMS, 2.0, 1.5):
        errs = [r["unbound_deg"] for r in rows if r["unbound_deg"] is not None
                and (r["bias_deg"] or 0.0) * k / pm.BIAS_PER_RMS <= pm.MAX_BIAS_DEG]
        worst = max(errs, default=float("nan"))
        out.append(f"{half}: bias bound at {k:g} × the residual: {len(errs)}/{len(rows)} answered, max error "
                   f"{worst:.2f}°, {sum(e > 1.0 for e in errs)} over 1°")
    return out


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
    ap.add_argument("--bias", action="store_true",
                    help="also the direction error with ProbeLight's bias bound off and the bias it measured, "
                         "and what the bound's factor at 2.0 and 1.5 would answer")
    ap.add_argument("--halo", action="store_true",
                    help="also, the true circle given, the halo's shift of a clipped highlight's direction and "
                         "the errors with and without the refinement")
    a = ap.parse_args(argv)
    halves = ["tune", "check"] if a.half == "both" else [a.half]
    print("| half | probe | r true (px) | r found | centre err (px) | direction err, found (°) | "
          "err, true circle given (°) | find CPU s | refusal |"
          + (" err, bias bound off (°) | bias measured (°) |" if a.bias else "")
          + (" halo's shift (°) | err refined (°) | err blob only (°) | err, old 1° bound (°) |" if a.halo else "")
          + "\n|---|---|---|---|---|---|---|---|---|" + ("---|---|" if a.bias else "")
          + ("---|---|---|---|" if a.halo else ""))
    summary = []
    for half in halves:
        rows = []
        for spec in varied(half, **({'n': a.n} if a.n else {}), scale=a.scale):
            if a.unclipped:
                spec = dataclasses.replace(spec, clip=False)
            rows.append(run_probe(spec, probe_image(spec, a.cache), bias=a.bias, halo=a.halo))
            print(_fmt(rows[-1], half), flush=True)
        for what, key in (("found", "err_deg"), ("answered with the true circle given", "given_deg")):
            errs = [r[key] for r in rows if isinstance(r[key], float)]
            summary.append(f"{half}: {len(errs)}/{len(rows)} {what}, max error "
                           f"{max(errs) if errs else float('nan'):.2f}°, {sum(e > 1.0 for e in errs)} over 1°, "
                           f"{len(rows) - len(errs)} refused")
        if a.bias:
            summary += _bias_summary(half, rows)
        if a.halo:
            summary += _halo_summary(half, rows)
    print("\n".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
