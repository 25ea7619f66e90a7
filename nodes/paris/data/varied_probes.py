"""A varied mirror-ball probe set (issue 26 item 7), drawn from seeds: Mitsuba 3 renders of
:mod:`nodes.paris.data.make_probes` with the ball at 10–40 % of the frame height (diameter), at
varied places, in front of dark, textured (skimage.data pictures) or grey backdrops, some the
back wall of a box (floor, ceiling, side walls), lit by the flash near the lens, the
environment and 0–2 other lamps (soft boxes whose reflection stays below clipping, or small bright
lamps that clip too), which cast the ball's shadow on the backdrop; exposures ×0.5 to ×1.5 (the flash's power set so that the backdrop is as bright at any distance).

The environment and the lamps are sampled 5× less often than the flash (``other_weight``:
the same expected image, far less Monte Carlo speckle on the flash-lit backdrop at 4 spp).

The TUNE half (seeds 0…, textures brick, grass, camera, coffee, 384×288 and 448×336 px) is
what the ball finder was developed on; the CHECK half (seeds 1000…, textures gravel, chelsea,
rocket, astronaut, moon, 400×300 and 512×384 px) was held apart.  Truth: ``make_probes.truth``.

``python -m nodes.paris.data.varied_probes OUT_DIR [tune|check]`` writes the EXRs and JSON
truths for inspection; benchmarks/bench_paris_probes.py prints the per-probe table.
"""
from __future__ import annotations

import sys

import numpy as np

from .make_probes import ProbeSpec

ENVS = ("city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset")
HALVES = {"tune": dict(seed0=0, textures=("brick", "grass", "camera", "coffee"), sizes=((384, 288), (448, 336))),
          "check": dict(seed0=1000, textures=("gravel", "chelsea", "rocket", "astronaut", "moon"),
                        sizes=((400, 300), (512, 384))),
          # drawn as the check half, from other seeds: read once, for the final numbers of a change
          # whose rules were set on the tune half (the check half having been read before)
          "holdout": dict(seed0=2000, textures=("gravel", "chelsea", "rocket", "astronaut", "moon"),
                          sizes=((400, 300), (512, 384)))}
N_PER_HALF = 12
SPP = 4


def varied(half: str, n: int = N_PER_HALF, spp: int = SPP, scale: int = 1) -> list[ProbeSpec]:
    """``n`` probes of ``half`` ('tune' or 'check'), the same on every call; ``scale``: each
    rendered at that many times its width and height (the same scene, the ball the same share
    of the frame, ``scale`` times as many pixels across it)."""
    import dataclasses

    cfg = HALVES[half]
    specs = [_spec(f"{half[0]}v{i:02d}", np.random.default_rng(cfg["seed0"] + i), cfg, spp) for i in range(n)]
    if scale != 1:
        specs = [dataclasses.replace(s, name=f"{s.name}x{scale}", width=s.width * scale, height=s.height * scale)
                 for s in specs]
    return specs


def _spec(name, rng, cfg, spp) -> ProbeSpec:
    w, h = cfg["sizes"][int(rng.integers(len(cfg["sizes"])))]
    R = 0.05
    frac = float(rng.uniform(0.1, 0.4))                 # ball diameter / frame height
    ortho = rng.random() < 0.1
    fov = None if ortho else float(rng.uniform(12, 30))
    if ortho:
        dist, ortho_h = 1.2, 2 * R / frac
    else:
        f = 0.5 * h / np.tan(np.radians(fov) / 2)
        dist, ortho_h = R / np.sin(np.arctan(frac * h / 2 / f)), 0.3
    mx, my = frac / 2 * h / w + 0.04, frac / 2 + 0.04     # the whole ball in the frame
    pos = (float(rng.uniform(mx, 1 - mx)), float(rng.uniform(my, 1 - my)))
    kind = rng.choice(["dark", "texture", "texture", "grey", "room"])
    texture = str(rng.choice(cfg["textures"])) if kind in ("texture", "room") and rng.random() < 0.8 else ""
    albedo = {"dark": rng.uniform(0.02, 0.06), "grey": rng.uniform(0.1, 0.3)}.get(kind, rng.uniform(0.05, 0.25))
    tint = rng.uniform(0.9, 1.1, 3)
    off = rng.uniform(-0.08, 0.08, 2)
    off = off if np.hypot(*off) > 0.02 else off + 0.03
    gap = float(rng.uniform(0.1, 0.8))
    power = float(rng.uniform(0.5, 1.5)) * ((dist + gap) / 1.6) ** 2     # the backdrop as bright at any distance
    return ProbeSpec(name, str(rng.choice(ENVS)), width=w, height=h, fov_deg=fov, ortho_height_m=ortho_h,
                     distance_m=float(dist), frame_pos=pos, backdrop_gap_m=gap,
                     backdrop_albedo=tuple(float(x) for x in np.clip(albedo * tint, 0, 0.9)), texture=texture,
                     room=kind == "room", lamps=_lamps(rng, dist), env_yaw_deg=float(rng.uniform(0, 360)),
                     env_level=float(rng.uniform(0.04, 0.25)), flash_offset_m=(float(off[0]), float(off[1]), 0.0),
                     flash_power=power, exposure=float(rng.choice([0.5, 1.0, 1.0, 1.5])),
                     roughness=float(rng.uniform(0.015, 0.05)), stick=bool(rng.random() < 0.3), spp=spp,
                     sensor_noise=float(rng.uniform(0.5, 2.0)), seed=int(rng.integers(1 << 16)), other_weight=0.2)


def _lamps(rng, dist) -> tuple:
    """0–2 lamps on the camera's side of the ball, 30–75° off the camera axis: a soft box
    (radius 0.15–0.3 m, radiance 0.1–0.5: reflection below clipping) or a small bright lamp (clipped)."""
    out = []
    for _ in range(int(rng.choice([0, 1, 1, 2]))):
        th, ph = np.radians(rng.uniform(30, 75)), rng.uniform(0, 2 * np.pi)
        d = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)])
        pos = np.array([0, 0, dist]) + d * rng.uniform(1.0, 2.0)
        if rng.random() < 0.7:
            out.append((tuple(float(x) for x in pos), float(rng.uniform(0.15, 0.3)), float(rng.uniform(0.1, 0.5))))
        else:
            out.append((tuple(float(x) for x in pos), 0.02, float(rng.uniform(300, 3000))))
    return tuple(out)


def main(argv=None):
    import json
    import os
    from dataclasses import asdict

    from nodes.io.images import encode_image

    from .make_probes import render, truth

    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__)
        return 2
    os.makedirs(argv[0], exist_ok=True)
    for half in argv[1:] or ["tune", "check"]:
        for spec in varied(half):
            with open(os.path.join(argv[0], f"{spec.name}.exr"), "wb") as f:
                f.write(encode_image(render(spec), ".exr", 16))
            with open(os.path.join(argv[0], f"{spec.name}.json"), "w") as f:
                json.dump({"spec": asdict(spec), "truth": truth(spec)}, f, indent=1)
            print("wrote", spec.name, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
