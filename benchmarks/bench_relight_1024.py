"""A new light on a cached face at 1024² (issue 26 item 6): Render through the photo camera plus
CompositeFace, against Render alone in the same run.

graphs/face_relight.yaml runs first (cached in ``--cache``: FaceMesh, the detail texture, the
fit — the preprocess); its `full_front` Render's inputs and the photo are then enlarged to
``--size``² (the photo bilinearly, the camera's intrinsics × size/512: the same face, 4× the
pixels at 1024²).  Each timed call relights with a light at an azimuth not used before (the
light-independent work — the surface, detail texture, eyes, mouth, and CompositeFace's alpha and
fill plan — is kept between calls, as a studio drag or a re-run of one light would find it);
the first ``--warmup`` calls, which prepare it, are left out.  Printed: the median and best wall
time, and the median CPU time of the process (all threads; on a shared machine other jobs
inflate the wall time, not that), of Render alone and of Render + CompositeFace, and their
ratio; and the same + the 8-bit sRGB PNG of the composite as the studio encodes a live view's
frame (``graphkit.studio.imaging``: display_rgb's LUT, PNG level 1).  The three are interleaved
call by call, so they see the same load.

    .venv/bin/python benchmarks/bench_relight_1024.py [--n 15] [--size 1024] [--profile]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def setup(cache: str, size: int):
    import cv2
    import numpy as np

    from graphkit import Image
    from graphkit.api import run_graph
    from nodes.paris.render import Render

    run = run_graph(ROOT / "graphs" / "face_relight.yaml", cache=cache, outputs=["portrait_front"], jobs=2)
    photo = run.value("photo.image").pixels[..., :3]
    h = photo.shape[0]
    inputs = run.graph.nodes["full_front"].map_inputs(lambda src, port: run.value(f"{src}.{port}"))
    cam = inputs["camera"]
    k = size / h
    inputs["camera"] = cam.model_copy(update={"width": size, "height": size, "fx": cam.fx * k, "fy": cam.fy * k,
                                              "cx": cam.cx * k, "cy": cam.cy * k})
    big = Image(np.ascontiguousarray(cv2.resize(photo, (size, size), interpolation=cv2.INTER_LINEAR)))
    params = Render.Params.model_validate(run.graph.nodes["full_front"].params)
    return inputs, params, big, run.value("l_front.light")


def main() -> int:
    from graphkit.memory import tune_malloc

    tune_malloc()  # as the CLI, the studio and Dask workers do
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=15)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")))
    ap.add_argument("--profile", action="store_true", help="cProfile one Render + CompositeFace call")
    args = ap.parse_args()
    import numpy as np

    from graphkit.studio.imaging import display_rgb, png
    from nodes.paris.composite import CompositeFace
    from nodes.paris.render import Render

    inputs, params, photo, light = setup(args.cache, args.size)
    render, comp = Render(params), CompositeFace(CompositeFace.Params())

    def lit(i):
        az = np.radians(-50 + 7.3 * i)
        d = np.array([np.sin(az), -0.2, -np.cos(az)])
        return {**inputs, "lights": [light.model_copy(update={"direction": tuple(d / np.linalg.norm(d))})]}

    def relight(i):
        return render.compute(**lit(i))

    def relight_composite(i):
        out = render.compute(**lit(i))
        return comp.compute(photo=photo, relit=out["image"], coverage=out["coverage"])

    def preview(i):  # as the studio sends a live view's frame (graphkit.studio.live)
        return png(display_rgb(relight_composite(i)["image"].pixels))

    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}, {args.size}², n={args.n}")
    results = {}
    runs = (("Render alone", relight), ("Render + CompositeFace", relight_composite),
            ("Render + CompositeFace + PNG", preview))
    times = {name: ([], []) for name, _ in runs}
    for i in range(args.n + args.warmup):  # interleaved: the three see the same load
        for name, fn in runs:
            c0, t0 = time.process_time(), time.perf_counter()
            fn(i)
            if i >= args.warmup:
                times[name][0].append((time.perf_counter() - t0) * 1e3)
                times[name][1].append((time.process_time() - c0) * 1e3)
    for name, (walls, cpus) in times.items():
        results[name] = statistics.median(walls), statistics.median(cpus)
        print(f"{name:<30} wall median {results[name][0]:7.1f} ms (best {min(walls):6.1f}), "
              f"CPU median {results[name][1]:7.1f} ms", flush=True)
    a, b = results["Render alone"], results["Render + CompositeFace"]
    print(f"ratio (Render + CompositeFace) / Render alone: wall {b[0] / a[0]:.2f}, CPU {b[1] / a[1]:.2f}")
    if args.profile:
        import cProfile
        import pstats

        pr = cProfile.Profile()
        pr.enable()
        relight_composite(args.n + args.warmup + 1)
        pr.disable()
        pstats.Stats(pr).sort_stats("tottime").print_stats(15)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
