"""A probe photo at a camera's size through ProbeLight: seconds and peak memory against its pixels.

The varied tune probe ``--probe`` (default tv40: a 10 %-of-the-frame ball) rendered at K× the
varied set's size (``--scales``, default 6 and 12: 2688×2016 = 5.4 MP and 5376×4032 = 21.7 MP;
``--cache`` keeps the renders, minutes each at 12×), then ProbeLight in a fresh process per
run, the ball found (``find_ball`` inside) and its true circle given: CPU and wall seconds, the
process's peak resident memory (and what the loaded image alone held), the flash direction's
error against make_probes.truth; with the circle given, also the median of 5 more computes
in the same process with the circle moved 0.3 px each (a drag step in the studio's probe view,
which runs ProbeLight's compute).  ``--peer DIR``: the same runs with another checkout's code
(e.g. a worktree of main), alternated with this one's.

Run:  .venv/bin/python benchmarks/bench_paris_probe_mp.py [--scales 6,12] [--cache DIR] [--peer DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: what each run does, in its own process with the code of the checkout on its sys.path
CHILD = r"""
import json, os, resource, sys, time
root, cache, name, K, mode = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
sys.path[:0] = [root, os.path.join(root, "benchmarks")]
from bench_paris_probes import _angle, probe_image
from graphkit import BadInput, Image
from nodes.paris.data.make_probes import truth
from nodes.paris.data.varied_probes import varied
from nodes.paris.probe import ProbeLight
spec = next(s for s in varied("tune", n=48, scale=K) if s.name == f"{name}x{K}")
img = probe_image(spec, cache or None)
t = truth(spec)
loaded = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
kw = dict(centre_x=t["centre_x"], centre_y=t["centre_y"], radius=t["radius"]) if mode == "given" else {}
c0, w0 = time.process_time(), time.perf_counter()
try:
    light = ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg, **kw)).compute(probe=Image(img))["light"]
    err, why = _angle(light.direction, t["direction"]), ""
except BadInput as e:
    err, why = None, e.message
cpu, wall = time.process_time() - c0, time.perf_counter() - w0
steps = []
if mode == "given":
    # the studio's probe view dragged: the same compute with the circle moved 0.3 px a step
    probe = Image(img)
    for i in range(1, 6):
        w1 = time.perf_counter()
        ProbeLight(ProbeLight.Params(fov_deg=spec.fov_deg, **{**kw, "centre_x": kw["centre_x"] + 0.3 * i})).compute(
            probe=probe)
        steps.append(time.perf_counter() - w1)
print(json.dumps({"cpu": cpu, "wall": wall, "err": err, "refused": why, "step": sorted(steps)[2] if steps else None,
                  "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, "image_gb": loaded / 1e6,
                  "size": f"{img.shape[1]}x{img.shape[0]}"}))
"""


def run(root: Path, cache: str, name: str, k: int, mode: str) -> dict:
    # (run from the cache folder: `python -c` puts the working directory first on sys.path)
    out = subprocess.run([sys.executable, "-c", CHILD, str(root), cache, name, str(k), mode], cwd=cache or "/",
                         capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"the run failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--probe", default="tv40")
    ap.add_argument("--scales", default="6,12")
    ap.add_argument("--cache", default="", help="folder that keeps the renders (.npy)")
    ap.add_argument("--peer", default=None, help="another checkout, run in turn with this one")
    a = ap.parse_args(argv)
    if a.cache:
        os.makedirs(a.cache, exist_ok=True)
    roots = [("this", ROOT)] + ([("peer", Path(a.peer).resolve())] if a.peer else [])
    print("| code | probe | size | circle | CPU s | wall s | peak GB (image alone) | error ° | drag step s |\n"
          "|---|---|---|---|---|---|---|---|---|")
    for k in [int(x) for x in a.scales.split(",")]:
        for mode in ("given", "found"):
            for name, root in roots:
                r = run(root, os.path.abspath(a.cache) if a.cache else "", a.probe, k, mode)
                err = f"{r['err']:.3f}" if r["err"] is not None else f"exit 2 ({r['refused'][:60]})"
                step = "—" if r.get("step") is None else f"{r['step']:.2f}"
                print(f"| {name} | {a.probe}x{k} | {r['size']} | {mode} | {r['cpu']:.1f} | {r['wall']:.1f} | "
                      f"{r['peak_gb']:.2f} ({r['image_gb']:.2f}) | {err} | {step} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
