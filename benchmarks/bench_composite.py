"""CompositeFace's seam figure (issue 26 item 1): is the mesh border visible in the relit photo?

graphs/face_relight.yaml's faces relit through the photo camera (`full_*` Render nodes: left
60, front, right 30, top 45, warm+cool) are put back into the astronaut photo four ways: a
naive paste (relit face where the mesh covers, the photo elsewhere), a plain alpha feather,
OpenCV's Poisson ``seamlessClone`` (through 8-bit sRGB), OpenCV's stitching blender
``cv2.detail.MultiBandBlender`` (5 bands, 16-bit integer images), and the Laplacian pyramid
(the node's default); all but the paste carry the change of light outward the same way.

Seam figure: the mean gradient magnitude of log luminance on the ring of pixels within 1.5 px
of the mesh border, composite over the photo's own (log: a smooth change of light does not
alter it, a step at the border does; goal ≤ 1.5×, 1 = the photo's own).  Also printed: the same with linear
luminance (composite / photo), and the step itself: the median |log| jump of luminance
between the pixels just inside and just outside the border (~3 px apart), over the photo's,
and the milliseconds each way takes at the photo's 512².

Writes ``--out``/seam_before_after.png: crops of the photo, the naive paste and the composite
at the `--picture` light, and their gradient magnitudes below.
Run:  .venv/bin/python benchmarks/bench_composite.py [--cache DIR] [--out DIR]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LIGHTS = ["left60", "front", "right30", "top", "two_lights"]
METHODS = ["paste", "alpha", "seamless", "cv_multiband", "pyramid"]
INT16_SCALE = 8000.0  # cv2.detail blends CV_16S images: linear [0, 1] × this keeps 13 bits


def luminance(img):
    return np.maximum(img[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32), 1e-4)


def grad_mag(y):
    gy, gx = np.gradient(y)
    return np.hypot(gx, gy)


def seam_figures(photo, comp, covered):
    """(log-gradient ratio, linear-gradient ratio, step ratio) on the mesh border's ring."""
    from scipy.ndimage import distance_transform_edt

    d_in, d_out = distance_transform_edt(covered), distance_transform_edt(~covered)
    ring = (covered & (d_in <= 1.5)) | (~covered & (d_out <= 1.5))
    yp, yc = luminance(photo), luminance(comp)
    log_ratio = grad_mag(np.log(yc))[ring].mean() / grad_mag(np.log(yp))[ring].mean()
    lin_ratio = grad_mag(yc)[ring].mean() / grad_mag(yp)[ring].mean()
    # step across the border: each pixel 1.5 px outside against the nearest pixel 1.5 px inside
    _, (iy, ix) = distance_transform_edt(~((d_in >= 1.5) & (d_in < 2.5)), return_indices=True)
    outer = ~covered & (d_out >= 1) & (d_out < 2)

    def step(y):
        return np.median(np.abs(np.log(y[outer]) - np.log(y[iy[outer], ix[outer]])))

    return float(log_ratio), float(lin_ratio), float(step(yc) / step(yp))


def cv_multiband(face, around, inside, bands=5):
    """OpenCV's stitching blender (cv2.detail.MultiBandBlender) of ``face`` where ``inside``
    and ``around`` elsewhere (binary masks: its pyramids smooth them)."""
    import cv2

    h, w = inside.shape
    blender = cv2.detail_MultiBandBlender(0, bands)
    blender.prepare((0, 0, w, h))
    for img, m in ((face, inside), (around, ~inside)):
        blender.feed(np.round(np.clip(img, 0, 4) * INT16_SCALE).astype(np.int16), m.astype(np.uint8) * 255, (0, 0))
    out, _ = blender.blend(None, None)
    return out.astype(np.float32) / INT16_SCALE


def composite_by(method, photo, relit, covered):
    from nodes.common.blend import feather
    from nodes.paris.composite import composite

    if method == "paste":
        return np.where(covered[..., None], relit, photo)
    size = np.sqrt(covered.sum())
    if method == "cv_multiband":  # the node's change of light outside, OpenCV's blender across
        _, ratio = composite(photo, relit, covered, 0.06 * size, 0.06 * size, "alpha")
        around = photo * ratio
        face = np.where(covered[..., None], relit, around)
        return cv_multiband(face, around, feather(covered, 0.06 * size) > 0.5)
    return composite(photo, relit, covered, 0.06 * size, 0.06 * size, method)[0]


def picture(photo, paste, comp, covered, path):
    import cv2

    from nodes.common.color import linear_to_srgb

    ys, xs = np.nonzero(covered)
    pad = 30
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad, covered.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad, covered.shape[1])
    tiles = []
    for img in (photo, paste, comp):
        tiles.append(np.clip(linear_to_srgb(np.clip(img[y0:y1, x0:x1], 0, 1)), 0, 1))
    grads = [grad_mag(np.log(luminance(img[y0:y1, x0:x1]))) for img in (photo, paste, comp)]
    top = np.percentile(grads[0], 99)
    row2 = [np.repeat(np.clip(g / top, 0, 1)[..., None], 3, -1) for g in grads]
    sheet = np.concatenate([np.concatenate(tiles, 1), np.concatenate(row2, 1)], 0)
    sheet = cv2.resize(sheet, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(path), np.round(sheet[..., ::-1] * 255).astype(np.uint8))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", default=str(ROOT / ".graphkit-cache"))
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_composite"))
    ap.add_argument("--picture", default="left60", choices=LIGHTS)
    args = ap.parse_args(argv)
    from graphkit.api import run_graph

    outs = [f"portrait_{name}" for name in LIGHTS]
    run = run_graph(ROOT / "graphs" / "face_relight.yaml", cache=args.cache, outputs=outs, jobs=2)
    photo = run.value("photo.image").pixels[..., :3]
    Path(args.out).mkdir(parents=True, exist_ok=True)
    print("seam figure: mean |grad log Y| on the mesh border's ring, composite / photo (goal <= 1.5); "
          "[linear |grad Y| ratio; border step ratio]")
    print(f"{'light':<11}" + "".join(f"{m:>31}" for m in METHODS))
    for name in LIGHTS:
        relit = run.value(f"full_{name}.image").pixels[..., :3]
        covered = run.value(f"full_{name}.coverage").alpha > 0.5
        row = []
        for m in METHODS:
            t = time.perf_counter()
            comp = composite_by(m, photo, relit, covered)
            ms = 1000 * (time.perf_counter() - t)
            g, lin, st = seam_figures(photo, comp, covered)
            row.append(f"{g:6.2f} [{lin:5.2f}; {st:5.2f}] {ms:4.0f}ms")
            if name == args.picture and m == "pyramid":
                picture(photo, composite_by("paste", photo, relit, covered), comp, covered,
                        Path(args.out) / "seam_before_after.png")
        print(f"{name:<11}" + "".join(f"{c:>31}" for c in row))
    print(f"picture: {Path(args.out) / 'seam_before_after.png'} (photo | naive paste | composite; "
          f"below: |grad log Y|), light {args.picture}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
