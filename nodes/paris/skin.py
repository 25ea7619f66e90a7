"""SkinSegment — where skin lies in the photograph (Paris, Sillion, Quan 2003, §3).

The paper either asks the user to paint the skin region (its Fig. 4) or uses "a segmentation
algorithm".  This node does both: a painted mask overrides; otherwise a colour model of skin is
learned from the face region and applied to it.
"""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Field, Image, In, Mask, Node

from .checks import check_rgb

#: chromaticity (u', v') of the D65 white point (CIE 1976 UCS)
_WHITE_UV = (0.19784, 0.46832)


class SkinSegment(Node):
    """Skin mask of a face photo (Paris 2003 §3, "skin segmentation"; Fig. 4).

    With ``painted``: the painted mask is the answer (values clipped to [0, 1]).  Otherwise a
    robust Gaussian model of skin chromaticity is learned from the ``face`` region less the
    ``exclude`` regions (e.g. FaceMesh's eyes, brows, lips, nostrils; holes in them, such as the
    mouth opening inside the lips, are excluded too):

    * features: CIE 1976 chromaticity (u', v') — independent of shading intensity — and L*;
    * model: median/MAD start, then iterated mean and covariance of the samples within
      ``max_sigma`` Mahalanobis units (reweighted until stable), so hair, shadowed creases and
      mis-registered landmarks do not pull it;
    * highlights: by the dichromatic model a skin pixel with a specular part lies on the segment
      from the skin chromaticity to the light's (taken as D65 white); such pixels are skin when
      they are brighter than the median skin lightness;
    * darkness: pixels darker than the robust L* range of skin (hair, nostrils) are rejected.

    Units: none (masks in [0, 1]).  An empty result is a bad input.
    """

    version = "1"
    inputs = {
        "image": In(Image, "the photo, linear RGB"),
        "painted": In(Mask, "user-painted skin mask; overrides the colour model", optional=True,
                      same_size_as="image"),
        "face": In(Mask, "region to learn skin from and to segment in (e.g. FaceMesh.face)", optional=True,
                   same_size_as="image"),
        "exclude": In(Mask, "regions that are never skin (eyes, brows, lips, nostrils, …)",
                      optional=True, variadic=True, same_size_as="image"),
    }
    outputs = {"mask": Mask}

    class Params(Node.Params):
        max_sigma: float = Field(3.0, gt=0, description="inlier distance of the chromaticity model (Mahalanobis units)")
        dark_sigma: float = Field(3.0, gt=0, description="pixels darker than median − dark_sigma·σ (L*, robust) are not skin")
        exclude_margin: float = Field(0.01, ge=0, description="dilation of the excluded regions, as a fraction of the face size")
        min_pixels: int = Field(50, ge=1, description="fewest face pixels to learn a colour model from")

    def compute(self, image: Image, painted: Mask | None = None, face: Mask | None = None,
                exclude: list[Mask] | Mask | None = None):
        h, w = image.pixels.shape[:2]
        if isinstance(exclude, Mask):
            exclude = [exclude]
        exclude = list(exclude or [])
        if painted is not None:
            a = np.clip(np.nan_to_num(painted.alpha), 0, 1).astype(np.float32)
            if not (a > 0).any():
                raise BadInput("painted", "the painted skin mask is empty")
            return Mask(a)
        check_rgb(image, "image")
        if face is None:
            raise BadInput("face", "connect a face region (e.g. FaceMesh.face) or a painted skin mask")
        region = face.alpha > 0.5
        if region.sum() < self.params.min_pixels:
            raise BadInput("face", f"the face region has {int(region.sum())} pixels; at least "
                                   f"{self.params.min_pixels} are needed to learn skin colour")
        banned = excluded_region(exclude, region, h, w, self.params.exclude_margin)
        left = int((region & ~banned).sum())
        if left < self.params.min_pixels:
            raise BadInput("exclude", f"the face region less the excluded regions leaves {left} pixels; "
                                      f"at least {self.params.min_pixels} are needed to learn skin colour")
        mask = segment(image.pixels[..., :3], region & ~banned, region & ~banned,
                       self.params.max_sigma, self.params.dark_sigma, self.params.min_pixels)
        if mask is None or not mask.any():
            raise BadInput("image", "no skin found in the face region (the colour model accepted no pixel)")
        return Mask(mask.astype(np.float32))


def excluded_region(masks: list[Mask], face: np.ndarray, h: int, w: int, margin: float) -> np.ndarray:
    """Union of the masks, holes filled, dilated by ``margin`` × the face's size — within the
    face's bounding box (it is taken from the face: a phone photo's clipped-pixel mask spans 12
    megapixels, the face a few per cent of them), False outside it."""
    from scipy import ndimage

    from nodes.common.blend import bounding_box

    out = np.zeros((h, w), bool)
    for m in masks:
        out |= m.alpha > 0.5
    if not out.any():
        return out
    out = ndimage.binary_fill_holes(out)
    ys, xs = np.nonzero(face)
    size = max(np.ptp(ys), np.ptp(xs)) + 1 if ys.size else max(h, w)
    r = int(round(margin * size))
    box = bounding_box(face) if ys.size else (slice(0, h), slice(0, w))
    if r > 0:
        # the dilation of the box r pixels wider, kept within the box: there it is the whole image's
        wide = bounding_box(face, pad=r) if ys.size else box
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        grown = ndimage.binary_dilation(out[wide], structure=(yy ** 2 + xx ** 2) <= r * r)
        inner = (slice(box[0].start - wide[0].start, box[0].stop - wide[0].start),
                 slice(box[1].start - wide[1].start, box[1].stop - wide[1].start))
        kept = grown[inner]
    else:
        kept = out[box]
    res = np.zeros((h, w), bool)
    res[box] = kept
    return res


def features(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear sRGB (..., 3) → CIE 1976 chromaticity (u', v') (..., 2) and L* (...)."""
    import colour

    from nodes.common.color import linear_srgb_to_luv

    luv = linear_srgb_to_luv(np.clip(np.asarray(rgb, np.float64), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = np.asarray(colour.Luv_to_uv(luv), np.float64)
    black = ~(luv[..., 0] > 1e-6) | ~np.isfinite(uv).all(-1)
    uv[black] = _WHITE_UV  # black has no chromaticity; it is rejected by lightness anyway
    return uv, luv[..., 0]


def robust_gaussian(x: np.ndarray, max_sigma: float, iters: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the inliers of samples x (N×D): median/MAD start, then iterated
    re-estimation from the samples within ``max_sigma`` Mahalanobis units."""
    mu = np.median(x, 0)
    mad = 1.4826 * np.median(np.abs(x - mu), 0)
    cov = np.diag(np.maximum(mad, 1e-9) ** 2)
    keep = None
    for _ in range(iters):
        d = x - mu
        m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
        new = m2 <= max_sigma ** 2
        if new.sum() < x.shape[1] + 2:
            break
        if keep is not None and np.array_equal(new, keep):
            break
        keep = new
        mu = x[keep].mean(0)
        # the covariance of a Gaussian truncated at max_sigma is smaller than the full one:
        # rescale so that the inlier radius stays max_sigma of the full distribution
        from scipy.stats import chi2

        dof = x.shape[1]
        shrink = chi2.cdf(max_sigma ** 2, dof + 2) / chi2.cdf(max_sigma ** 2, dof)
        cov = np.cov(x[keep].T).reshape(dof, dof) / shrink + np.eye(dof) * 1e-12
    return mu, cov


def segment(rgb, learn, where, max_sigma, dark_sigma, min_pixels):
    """Boolean skin mask inside ``where`` from a model learned on ``learn`` pixels (or None).
    Only the box holding both is looked at (a face is a small part of a phone's 12 megapixels)."""
    if learn.sum() < min_pixels:
        return None
    ys, xs = np.nonzero(learn | where)
    box = (slice(int(ys.min()), int(ys.max()) + 1), slice(int(xs.min()), int(xs.max()) + 1))
    out = np.zeros(where.shape, bool)
    got = _segment(rgb[box], learn[box], where[box], max_sigma, dark_sigma, min_pixels)
    if got is None:
        return None
    out[box] = got
    return out


def _segment(rgb, learn, where, max_sigma, dark_sigma, min_pixels):
    uv, lstar = features(rgb)
    luv_learn = uv[learn]
    l_learn = lstar[learn]
    # learn chromaticity on the pixels of ordinary brightness (no highlight, no deep shadow)
    lo, hi = np.percentile(l_learn, [10, 90])
    core = (l_learn >= lo) & (l_learn <= hi)
    mu, cov = robust_gaussian(luv_learn[core] if core.sum() >= min_pixels else luv_learn, max_sigma)
    icov = np.linalg.inv(cov)
    d = uv - mu
    m2 = np.einsum("...i,ij,...j->...", d, icov, d)
    chroma_ok = m2 <= max_sigma ** 2
    # dichromatic highlights: on the segment skin → white, off it by < max_sigma
    seg = np.asarray(_WHITE_UV) - mu
    seg_len = np.linalg.norm(seg)
    t = np.clip(d @ (seg / max(seg_len, 1e-12)), 0, seg_len)
    r = d - t[..., None] * (seg / max(seg_len, 1e-12))
    r2 = np.einsum("...i,ij,...j->...", r, icov, r)
    l_skin = lstar[learn & chroma_ok]
    if l_skin.size < min_pixels:
        return None
    l_med = np.median(l_skin)
    l_mad = 1.4826 * np.median(np.abs(l_skin - l_med))
    highlight = (r2 <= max_sigma ** 2) & (lstar >= l_med)
    bright_enough = lstar >= l_med - dark_sigma * max(l_mad, 1e-6)
    return where & (chroma_ok | highlight) & bright_enough
