"""CompositeFace (issue 26 item 1) on an analytic case: a textured Lambertian sphere filling
most of a photo, lit from one direction; the "face" (what the mesh covers) is a disc in its
middle, relit exactly to a second direction.  The true whole photograph under the second
light is known everywhere, so the composite is checked inside the face, across the seam and
outside it (the sphere beyond the face stands for forehead, ears and neck)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import BadInput, Image, Mask
from nodes.common.blend import feather, laplacian_blend, smooth_fill
from nodes.paris.composite import CompositeFace, composite

N = 256
FACE_R = 60.0


def _scene():
    yy, xx = np.mgrid[0:N, 0:N].astype(np.float64) + 0.5
    cx, cy, R = N / 2, N / 2 + 10, 150.0
    x, y = (xx - cx) / R, (yy - cy) / R
    on = x * x + y * y < 1
    z = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    n = np.stack([x, -y, z], -1)
    rng = np.random.default_rng(3)
    albedo = 0.45 + 0.25 * rng.random((N, N, 3))  # pixel-scale texture: the "detail" the ratio keeps
    albedo[..., 0] *= 1.2

    def lit(d):
        d = np.asarray(d, float) / np.linalg.norm(d)
        img = albedo * (0.08 + 0.9 * np.clip(n @ d, 0, None))[..., None]
        img[~on] = 0.2 * albedo[~on]  # a dim wall behind: the ratio there is not the sphere's
        return img.astype(np.float32)

    photo, truth = lit([0.1, 0.2, 1.0]), lit([-0.5, 0.3, 0.8])
    r_face = np.hypot(xx - cx, yy - cy)
    face = r_face < FACE_R
    relit = np.where(face[..., None], truth, 0.0).astype(np.float32)
    return photo, truth, relit, face, r_face, on


def _rel_err(a, b, where):
    return float(np.mean(np.abs(a[where] - b[where])) / np.mean(b[where]))


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.mark.parametrize("method", ["pyramid", "alpha"])
def test_analytic_sphere_inside_seam_outside(scene, method):
    photo, truth, relit, face, r, on = scene
    band = 0.06 * np.sqrt(face.sum())
    out, ratio = composite(photo, relit, face, band, band, method)  # the node's defaults
    inside = r < FACE_R - 2 * band
    seam = (r > FACE_R - 2 * band) & (r < FACE_R + 4)
    outside = on & (r > FACE_R + 4) & (r < FACE_R + 30)
    # inside: the relit face itself
    assert _rel_err(out, truth, inside) < 0.01
    # across the seam: within 3 % of the truth (measured 1.7 %)
    assert _rel_err(out, truth, seam) < 0.03
    # outside (up to half the face's radius beyond it): the photo under its old light is 29 % off;
    # the change of light carried outward (its value at the border, not its slope): 11.7 %
    untouched = _rel_err(photo, truth, outside)
    assert untouched > 0.25
    assert _rel_err(out, truth, outside) < min(0.13, untouched / 2)
    # the texture outside is the photo's (only the light changed): the ratio is smooth
    assert np.abs(np.diff(np.log(ratio[..., 1]), axis=1)).max() < 0.05


def test_no_seam_in_the_log_gradient(scene):
    """A naive paste leaves a step at the mesh border; the composite does not: the gradient of
    log intensity across the border stays at the photo's own (its texture)."""
    photo, truth, relit, face, r, on = scene
    band = 0.06 * np.sqrt(face.sum())
    comp, _ = composite(photo, relit, face, band, band)
    paste = np.where(face[..., None], relit, photo)
    ring = (r > FACE_R - 1.5) & (r < FACE_R + 1.5)

    def glog(img):
        g = np.log(np.maximum(img.mean(-1), 1e-4))
        gy, gx = np.gradient(g)
        return float(np.mean(np.hypot(gx, gy)[ring]))

    assert glog(paste) > 1.5 * glog(truth)
    assert glog(comp) < 1.2 * glog(truth)


def test_smooth_fill_keeps_weighted_values_and_extends_them():
    yy, xx = np.mgrid[0:128, 0:128]
    field = (0.01 * xx + 0.02 * yy).astype(np.float32)  # a linear ramp: smooth at any scale
    r = np.hypot(xx - 64, yy - 64)
    w = (r < 30).astype(np.float32)
    est = smooth_fill(field, w, 1.0)
    assert np.abs(est - field)[r < 26].max() < 5e-4  # a ramp is kept exactly away from the border
    # outside: the values at the border carried outward, never beyond them
    assert field[r < 30].min() - 1e-3 <= est.min() and est.max() <= field[r < 30].max() + 1e-3
    assert np.abs(np.diff(est, axis=0)).max() < 0.03 and np.abs(np.diff(est, axis=1)).max() < 0.03


def test_laplacian_blend_is_exact_where_alpha_is_flat():
    rng = np.random.default_rng(0)
    a, b = rng.random((64, 64, 3), np.float32), rng.random((64, 64, 3), np.float32)
    assert np.allclose(laplacian_blend(a, b, np.ones((64, 64), np.float32)), a, atol=1e-5)
    assert np.allclose(laplacian_blend(a, b, np.zeros((64, 64), np.float32)), b, atol=1e-5)


def test_mesh_not_on_the_photo_is_refused(scene):
    from graphkit.contract import compute_checked

    photo, _, relit, face, _, _ = scene
    with pytest.raises(BadInput) as e:
        compute_checked(CompositeFace(), photo=Image(photo), relit=Image(relit),
                        coverage=Mask(np.zeros_like(face, np.float32)))
    assert e.value.port == "coverage" and "does not overlap" in e.value.message
    with pytest.raises(BadInput) as e:  # a face rendered through another camera (a close-up)
        compute_checked(CompositeFace(), photo=Image(photo), relit=Image(relit[:100]),
                        coverage=Mask(face.astype(np.float32)))
    assert e.value.port == "relit"


def test_pyramid_on_the_face_box_is_the_whole_photo_pyramid():
    """CompositeFace 3 blends on the face's box widened by the coarsest level's reach
    (blend_region): within 1 % of the whole photo's pyramid, and the photo × ratio again at the
    box's border (no step where the box ends)."""
    import cv2

    from nodes.paris.composite import composite, prepare

    rng = np.random.default_rng(0)
    H = W = 300
    photo = cv2.GaussianBlur(rng.uniform(0.2, 0.8, (H, W, 3)).astype(np.float32), (0, 0), 3)
    yy, xx = np.mgrid[:H, :W]
    cov = (yy - 120) ** 2 + (xx - 170) ** 2 < 50 ** 2
    relit = photo * (1.2 + 0.7 * xx / W)[..., None].astype(np.float32)
    pr = prepare(photo, cov, 6.0, 6.0)
    out, ratio = composite(photo, relit, cov, 6.0, 6.0, prepared=pr)
    around = photo * ratio
    whole = laplacian_blend(np.where(cov[..., None], relit, around), around, pr.alpha)
    assert np.abs(out / whole - 1).max() < 0.01
    ys, xs = pr.blend_box
    assert (ys.stop - ys.start) * (xs.stop - xs.start) < H * W / 4
    inner = np.zeros((H, W), bool)
    inner[ys.start + 2:ys.stop - 2, xs.start + 2:xs.stop - 2] = True
    edge = ~inner
    edge[:ys.start] = edge[ys.stop:] = False
    edge[:, :xs.start] = edge[:, xs.stop:] = False
    assert np.abs(out[edge] / around[edge] - 1).max() < 1e-3


def test_feather_on_the_mask_box_is_the_whole_image_feather():
    """feather works on the box round the mask (a face in a 12-megapixel photo): the same alpha,
    bit for bit, as the smoothstep of scipy's distance transform over the whole image — masks
    at the border, ragged, one pixel, empty."""
    from scipy.ndimage import distance_transform_edt

    rng = np.random.default_rng(0)
    for k in range(150):
        h, w = rng.integers(5, 60, 2)
        m = np.zeros((h, w), bool)
        y0, x0 = rng.integers(0, h), rng.integers(0, w)
        m[y0:y0 + rng.integers(1, 30), x0:x0 + rng.integers(1, 30)] = True
        m &= rng.random((h, w)) > 0.1 * (k % 3)
        width = rng.uniform(0.5, 9)
        t = np.clip(distance_transform_edt(m) / width, 0, 1)
        assert np.array_equal(feather(m, width), (t * t * (3 - 2 * t)).astype(np.float32)), k
    assert not feather(np.zeros((4, 5), bool), 2.0).any()
