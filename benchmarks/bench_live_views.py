"""The makeup, blush (issue 28) and composite (issue 26) live views: slider → the view's next
frame, on the whole photo at 1024².

The studio's own frame path, ``graphkit.studio.live.frame_bytes`` (the view's ``frame``, then
the PNG at level 0 as sent to a page on the loopback), of ``MakeupView`` on ``made_up``
(CosmeticShade, graphs/makeup.yaml) and ``BlushView`` on ``rig`` (AppearanceRig →
ApplyHemoglobin, graphs/blush.yaml).  The graphs run first (cached in ``--cache``); the
views then read their node's inputs, the astronaut's 512² ones resized to 1024² (images and
masks of the photo's size bilinearly, the camera's intrinsics × 2: the same face, 4× the
pixels).  Each move sets a slider to a value not used before (CosmeticShade builds that
thickness's spectral table; the composite view relights `full_top` at a new azimuth and
composites it, ``CompositeView`` on graphs/face_relight.yaml's ``portrait_top``); the first ``--warmup`` moves (the view's first frame prepares the
surface, SSS plan and specular terms) are left out.  The browser's websocket and decode are not
included (see benchmarks/bench_studio.py for those).  The CPU time of the process per move (all
threads) is printed too: on a shared machine other jobs inflate the wall time, not that.

    .venv/bin/python benchmarks/bench_live_views.py [--n 20] [--size 1024] [--views makeup,blush,composite]
        [--preview-max-px N]

At sizes over ``CompositeView.PREVIEW_MAX_PX`` (1.5 MP) the composite view makes its frames on
the photo reduced by a whole factor (``--size 3024``: 1008×1008); ``--preview-max-px 0`` makes
them at the full size, the peer.
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


class Studio:
    """What a live view reads of the studio: the graph and its nodes' input values (resized)."""

    def __init__(self, run, size: int):
        self.graph, self.run, self.size = run.graph, run, size
        self.photo = run.value("photo.image").pixels.shape[:2]  # both graphs' LoadImage
        self.kept = {}

    def input_values(self, node: str) -> dict:
        # resized once (the studio's values are the run's, not made again per frame)
        if node not in self.kept:
            vals = self.graph.nodes[node].map_inputs(lambda src, port: self.run.value(f"{src}.{port}"))
            self.kept[node] = {k: resized(v, self.photo, self.size) for k, v in vals.items()}
        return dict(self.kept[node])


def resized(v, shape, size: int):
    import cv2
    import numpy as np

    from graphkit import Camera, Image, Mask

    if isinstance(v, list):
        return [resized(x, shape, size) for x in v]
    if isinstance(v, Image) and v.pixels.shape[:2] == shape:
        px = cv2.resize(np.ascontiguousarray(v.pixels), (size, size), interpolation=cv2.INTER_LINEAR)
        return Image(px.reshape(size, size, -1), v.colorspace)
    if isinstance(v, Mask) and v.alpha.shape == shape:
        return Mask(cv2.resize(v.alpha, (size, size), interpolation=cv2.INTER_LINEAR))
    if isinstance(v, Camera) and (v.height, v.width) == shape:
        sy, sx = size / shape[0], size / shape[1]
        return v.model_copy(update={"width": size, "height": size, "fx": v.fx * sx, "fy": v.fy * sy,
                                    "cx": v.cx * sx, "cy": v.cy * sy})
    return v


def bench(name, view, key, values, n, warmup):
    from graphkit.studio.live import frame_bytes

    times, computes, cpus, first = [], [], [], None
    info = {}
    for i, x in enumerate(values[: n + warmup]):
        c0, t0 = time.process_time(), time.perf_counter()
        info, _ = frame_bytes(view, {key: x}, 0.0, level=0)
        first = first or (time.perf_counter() - t0) * 1e3
        if i >= warmup:
            times.append((time.perf_counter() - t0) * 1e3)
            cpus.append((time.process_time() - c0) * 1e3)
            computes.append(info["compute_ms"])
    print(f"{name} ({info['width']}×{info['height']}, slider '{key}'): median {statistics.median(times):.1f} ms, "
          f"best {min(times):.1f} ms, worst {max(times):.1f} ms (n={len(times)}); of which the view's frame "
          f"median {statistics.median(computes):.1f} ms, the PNG the rest; first frame {first:.0f} ms; CPU time "
          f"of this process per move median {statistics.median(cpus):.1f} ms (all threads)", flush=True)


def main() -> int:
    from graphkit.memory import tune_malloc

    tune_malloc()  # as the CLI, the studio and Dask workers do
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")))
    ap.add_argument("--views", default="makeup,blush,composite", help="which views, comma-separated")
    ap.add_argument("--preview-max-px", type=int, default=None,
                    help="the composite view's CompositeView.PREVIEW_MAX_PX (0: frames at the photo's full size)")
    args = ap.parse_args()
    views = args.views.split(",")
    from graphkit.api import run_graph
    from nodes.huang.studio_view import MakeupView
    from nodes.jimenez.studio_view import BlushView

    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    steps = [1.0 + 0.013 * (i + 1) * (-1) ** i for i in range(args.n + args.warmup)]
    if "makeup" in views:
        makeup = Studio(run_graph(ROOT / "graphs" / "makeup.yaml", cache=args.cache), args.size)
        bench("makeup (CosmeticShade 'made_up')", MakeupView(makeup, "made_up"), "layer0", steps, args.n, args.warmup)
    if "blush" in views:
        blush = Studio(run_graph(ROOT / "graphs" / "blush.yaml", cache=args.cache), args.size)
        bench("blush (AppearanceRig 'rig' → 'recolor')", BlushView(blush, "rig"), "w1",
              [min(1.0, 0.5 * s) for s in steps], args.n, args.warmup)
    if "composite" in views:  # the light of `full_top` moved, the whole photo relit
        from nodes.paris.studio_view import CompositeView

        if args.preview_max_px is not None:
            CompositeView.PREVIEW_MAX_PX = args.preview_max_px or 1 << 62
        face = Studio(run_graph(ROOT / "graphs" / "face_relight.yaml", cache=args.cache, outputs=["portrait_top"]),
                      args.size)
        bench("composite (CompositeFace 'portrait_top', Render 'full_top')", CompositeView(face, "portrait_top"),
              "azimuth", [-40.0 + 3.7 * i for i in range(args.n + args.warmup)], args.n, args.warmup)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
