"""Before/after crops of issue 26 item 3 for nodes/paris/README.md: the demo's `top 45` close-up
(graphs/face_relight.yaml) at the mouth and at the cheek's silhouette, rendered as before (the
mouth shaded as skin, binary coverage) and as now (the mouth from the photo's detail under the
skin's smooth shading, antialiased silhouette), enlarged 4× without interpolation.  Printed:
the bright outliers in the mouth (relit / photo > 1.5 × its median there, as
tests/test_paris_artefacts.py counts them) and the pixels of fractional coverage (none on a
staircase).

    .venv/bin/python benchmarks/artefact_crops.py [--cache DIR] [--out docs/paris_artefacts.png]
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")))
    ap.add_argument("--out", default=str(ROOT / "docs" / "paris_artefacts.png"))
    args = ap.parse_args()
    import cv2

    from graphkit.api import run_graph
    from nodes.common.color import linear_to_srgb
    from nodes.paris.render import Render, mouth_region

    run = run_graph(ROOT / "graphs" / "face_relight.yaml", cache=args.cache, outputs=["top"], jobs=2)
    inputs = run.graph.nodes["top"].map_inputs(lambda src, port: run.value(f"{src}.{port}"))
    params = Render.Params.model_validate(run.graph.nodes["top"].params).model_dump()
    photo = run.value("view.image").pixels[..., :3]
    alpha, _ = mouth_region(inputs["mesh"], inputs["camera"])
    m = alpha > 0.5
    tiles = []
    for name, upd in (("before", {"mouth": "skin", "antialias": False}), ("after", {})):
        out = Render(Render.Params.model_validate({**params, **upd})).compute(**inputs)
        img, cov = out["image"].pixels, out["coverage"].alpha
        ratio = img.mean(2) / np.maximum(photo.mean(2), 1e-3)
        n = int((ratio[m] > 1.5 * np.median(ratio[m])).sum())
        print(f"{name}: {n} of {int(m.sum())} mouth pixels brighter than 1.5 × the median relit/photo; "
              f"{int(((cov > 0) & (cov < 1)).sum())} pixels of fractional coverage")
        srgb = np.clip(linear_to_srgb(np.clip(img, 0, 1)), 0, 1)
        ys, xs = np.nonzero(m)
        mouth = srgb[ys.min() - 6:ys.max() + 6, xs.min() - 6:xs.max() + 6]
        h = mouth.shape[0]
        y0 = (ys.min() + ys.max()) // 2 - h // 2  # the cheek's silhouette beside the mouth
        x1 = int(np.nonzero(cov[y0 + h // 2] > 0.5)[0].max())
        jaw = srgb[y0:y0 + h, x1 - h // 2:x1 - h // 2 + h]
        tiles.append(np.concatenate([mouth, np.ones((mouth.shape[0], 2, 3)), jaw], 1))
    sheet = np.concatenate([tiles[0], np.ones((2, tiles[0].shape[1], 3)), tiles[1]], 0)
    sheet = cv2.resize(sheet, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(args.out, np.round(sheet[..., ::-1] * 255).astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out}: top row before, bottom row after; the mouth, then the cheek's silhouette")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
