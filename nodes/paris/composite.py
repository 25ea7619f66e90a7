"""CompositeFace — the relit face put back into the whole photograph (Paris 2003 §1, §6)."""
from __future__ import annotations

import threading
from typing import Literal, NamedTuple, Optional

import numpy as np
import xxhash

from graphkit import BadInput, Field, Image, In, Mask, Node, Out
from graphkit.hashing import canonical
from graphkit.store import value_parts

LOG_RATIO_LIMIT = float(np.log(32.0))  # a change of light beyond ×32 / ÷32 is not trusted
DARK = 0.01  # photo pixels darker than this (linear) carry no usable ratio (pupils, black hair)
CLIPPED = 0.999  # photo pixels at the sensor's top carry no usable ratio either
FILL_GRID_SIGMA = 2.0  # the change of light is filled on a grid where its σ is ≥ 2 px (SmoothFill)


class Prepared(NamedTuple):
    """What :func:`composite` needs that does not depend on the relit face (the photo, the
    coverage and the two widths only): the photo, its feathered alpha, the fill of the change
    of light from the face's trusted pixels."""
    photo: np.ndarray
    covered: np.ndarray
    alpha: np.ndarray
    fill: object  # blend.SmoothFill
    box: tuple[slice, slice]  # the trusted pixels' bounding box
    blend_box: tuple[slice, slice]  # where the pyramid blends: blend_region()
    levels: int  # the pyramid's levels there


def blend_region(covered: np.ndarray) -> tuple[tuple[slice, slice], int]:
    """(the box the Laplacian pyramid blends the face in, its number of levels): the face's
    bounding box with levels down to ~16 px of it, widened on each side by 2^(levels + 1) px
    (the reach of the coarsest level's mask, so the blend is the photo's again at the box's
    border), within the photo.  Outside the box the face and its surround are the same image:
    the whole photo's pyramid would only reconstruct it."""
    from nodes.common.blend import _pyramid_sizes

    ys, xs = np.nonzero(covered)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    levels = max(1, sum(1 for s in _pyramid_sizes(y1 - y0, x1 - x0) if min(s) >= 16))
    pad = 2 ** (levels + 1)
    H, W = covered.shape
    return (slice(max(0, y0 - pad), min(H, y1 + pad)), slice(max(0, x0 - pad), min(W, x1 + pad))), levels


def prepare(photo: np.ndarray, covered: np.ndarray, band_px: float, scale_px: float) -> Prepared:
    """:class:`Prepared` for :func:`composite`; ValueError when no face pixel is lit and
    unclipped in the photo."""
    from nodes.common.blend import SmoothFill, feather

    photo = photo.astype(np.float32)
    alpha = feather(covered, band_px)
    lum = photo.mean(axis=2)
    trust = alpha * ((lum > DARK) & (photo.max(axis=2) < CLIPPED))
    if not (trust > 0).any():
        raise ValueError("no face pixel is lit and unclipped in the photo")
    ys, xs = np.nonzero(trust > 0)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    return Prepared(photo, covered, alpha, SmoothFill(trust, scale_px, FILL_GRID_SIGMA), box, *blend_region(covered))


def composite(photo: np.ndarray, relit: np.ndarray, covered: np.ndarray, band_px: float,
              scale_px: float, method: str = "pyramid",
              prepared: Prepared | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(the composited image, the change of light applied outside the face as a ratio image).

    Outside the face the photo is multiplied by the change of light relit/photo measured on
    the face, smoothed to ``scale_px`` and carried outward (``smooth_fill``);
    the relit face is blended into that over a ``band_px`` feather inside the mesh border
    (``method``: Laplacian pyramid, OpenCV seamlessClone, or a plain alpha feather).
    ``prepared``: :func:`prepare` of the same photo, coverage and widths, kept from an earlier
    call (a new light)."""
    from nodes.common.blend import laplacian_blend, seamless_clone

    pr = prepared or prepare(photo, covered, band_px, scale_px)
    photo, alpha = pr.photo, pr.alpha
    relit = np.asarray(relit, np.float32)
    box = pr.box  # the change of light is measured where the fill weighs it: the face's box
    log_ratio = np.clip(np.log(np.maximum(relit[box], 1e-6) / np.maximum(photo[box], 1e-6)),
                        -LOG_RATIO_LIMIT, LOG_RATIO_LIMIT)
    ratio = np.exp(pr.fill(log_ratio, box)).astype(np.float32, copy=False)
    around = photo * ratio
    if method == "pyramid":  # on the face's box (blend_region); the photo × ratio around it
        bb = pr.blend_box
        face = np.where(covered[bb][:, :, None], relit[bb], around[bb])
        out = around
        out[bb] = laplacian_blend(face, around[bb], alpha[bb], pr.levels)
        return np.clip(out, 0.0, None, out=out), ratio
    face = np.where(covered[:, :, None], relit, around)
    if method == "seamless":
        out = seamless_clone(face, around, alpha > 0.5)
    else:
        out = alpha[:, :, None] * face + (1.0 - alpha[:, :, None]) * around
    return np.clip(out, 0.0, None).astype(np.float32), ratio


class CompositeFace(Node):
    """The whole photograph relit: the relit face (Render through the photo camera, at the
    photo's size) blended into the photo, and the rest of the photo — forehead under the hair
    line, ears, neck, hair, background — following the same change of light at low frequency.

    * The change of light is the ratio relit / photo on the face (smooth: the relit face is the
      new Phong shading × the detail texture, the photo the old shading × the same texture),
      taken on the face's lit, unclipped pixels away from the mesh border, smoothed to
      ``scale`` (normalized convolution of its log) and carried outward smoothly (``smooth_fill``);
      outside the face the photo is multiplied by it, so a neck is not left lit by the old flash.
    * The relit face is blended in over a ``feather`` band inside the mesh border: multi-band
      (Laplacian pyramid, the default), OpenCV's Poisson ``seamless`` clone, or a plain
      ``alpha`` feather.  On benchmarks/bench_composite.py's seam figure (log gradient on the
      border, composite / photo; goal ≤ 1.5, the naive paste 1.37–1.70) all three meet it:
      pyramid 0.97–0.99, seamless 1.01–1.02 (the closest to the photo's own 1, but it clones
      8-bit sRGB, so the whole linear photo comes back quantised and clipped to 1), alpha
      0.98–1.03 (its border step 0.86–1.05 against the pyramid's 0.88–1.03).  The pyramid
      stays the default: float throughout, within 10 % of the photo's own gradient.

    ``feather`` and ``scale`` default to 6 % of the face's size (the square root of
    its pixel area).  Outputs the image and the ratio applied outside the face.
    """

    studio_view = "nodes.paris.studio_view:CompositeView"  # graphkit serve: move the light, see the photo
    version = "4"  # 4: blurred through SciPy (the same bytes on every CPU; 3 used OpenCV, whose AVX2 and AVX-512 kernels round differently); 2: the change of light filled on a grid coarser by σ // 4 (the same at ≤ 8 px)
    # 3: the pyramid blends on the face's box widened by its coarsest level's reach (blend_region);
    #    the change of light filled on a grid coarser by σ // 2
    inputs = {"photo": In(Image, "the input photograph (linear RGB)", channels=3),
              "relit": In(Image, "the relit face rendered through the photo camera (Render.image)",
                          channels=3, same_size_as="photo"),
              "coverage": In(Mask, "the pixels the relit face covers (Render.coverage)", same_size_as="photo")}
    outputs = {"image": Out(Image, "the photograph with the new light, its size"),
               "ratio": Out(Image, "the change of light applied around the face (relit / photo, smooth)")}

    class Params(Node.Params):
        method: Literal["pyramid", "seamless", "alpha"] = Field(
            "pyramid", description="how the face is blended in: Laplacian pyramid, OpenCV seamlessClone, alpha feather")
        feather: Optional[float] = Field(None, gt=0, description="feather band inside the mesh border, pixels "
                                                                 "(default 6 % of the face's size)")
        scale: Optional[float] = Field(None, gt=0, description="finest scale of the change of light carried "
                                                               "outside the face, pixels (default 6 % of its size)")

    def compute(self, photo: Image, relit: Image, coverage: Mask):
        p = self.params
        ph, rl = photo.pixels, relit.pixels  # sizes and channels: the ports' constraints
        covered = coverage.alpha > 0.5
        area = int(covered.sum())
        if area < 64:
            raise BadInput("coverage", f"the relit face covers {area} pixels of the photo (fewer than 64): the "
                                       "mesh does not overlap the photo; check the mesh and the camera")
        size = float(np.sqrt(area))
        band, scale = p.feather or 0.06 * size, p.scale or 0.06 * size
        key = xxhash.xxh3_128(canonical([value_parts(self.in_ports["photo"].type, photo)[2],
                                         value_parts(self.in_ports["coverage"].type, coverage)[2],
                                         band, scale])).hexdigest()
        pr = _PREPARED.get(key)
        if pr is None:
            try:
                pr = prepare(ph, covered, band, scale)
            except ValueError as e:
                raise BadInput("photo", f"{e}: nothing to measure the change of light on") from None
            with _PREPARED_LOCK:  # nodes may run on several threads (graphkit run --jobs)
                while len(_PREPARED) >= 4:
                    _PREPARED.pop(next(iter(_PREPARED)))
                _PREPARED[key] = pr
        img, ratio = composite(ph, rl, covered, band, scale, p.method, pr)
        return {"image": Image(img), "ratio": Image(ratio)}


#: the last prepare() results by the digest of the photo, the coverage and the widths (a live
#: view's or a benchmark's new light on the same face: ~0.1 GB for a 1024² photo)
_PREPARED: dict = {}
_PREPARED_LOCK = threading.Lock()
