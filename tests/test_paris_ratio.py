"""RatioImage (Paris 2003 §3, the detail texture T = photo / shaded face) against its closed form,
numpy only: T = a / max(b, eps) per channel.  Before issue 10 only the OpenCL conformance test
noticed ``a / (b + eps)`` (so without OpenCL nothing did)."""
import numpy as np
import pytest

from graphkit import Image
from nodes.paris.ratio import RatioImage, ratio


def _closed_form(a, b, eps):
    """float64 a / max(b, eps), rounded once to float32 (what one IEEE division gives)."""
    return (a.astype(np.float64) / np.maximum(b.astype(np.float64), float(np.float32(eps)))).astype(np.float32)


@pytest.mark.parametrize("eps", [1e-4, 0.25])
def test_ratio_is_a_over_max_b_eps(eps):
    b_vals = np.array([0.0, eps / 4, eps / 2, eps, 2 * eps, 1e-3, 0.5, 1.0, 7.0], np.float32)
    a_vals = np.array([0.0, 1e-5, 0.3, 1.0, 4.5], np.float32)
    a = np.repeat(a_vals[:, None], len(b_vals), 1)[..., None].repeat(3, -1)
    b = np.repeat(b_vals[None, :], len(a_vals), 0)[..., None].repeat(3, -1)
    b[..., 1] *= 3.0  # channels differ
    ref = _closed_form(a, b, eps)
    r = ratio(a, b, eps)
    assert r.dtype == np.float32
    np.testing.assert_array_equal(r, ref)  # a/(b+eps) is off by eps/b (2e-4 at b=0.5)
    out = RatioImage(RatioImage.Params(eps=eps)).compute(a=Image(a, "acescg"), b=Image(b))
    assert out.pixels.dtype == np.float32 and out.colorspace == "acescg"  # a's tag is kept
    np.testing.assert_array_equal(out.pixels, ref)
    # below the floor the ratio is a / eps exactly; above it, a / b
    assert out.pixels[3, 0, 0] == np.float32(1.0) / np.float32(eps)
    np.testing.assert_array_equal(out.pixels[:, 6, 0], a_vals / np.float32(0.5))


def test_one_channel_denominator_serves_every_channel():
    rng = np.random.default_rng(8)
    a = rng.random((5, 7, 3), dtype=np.float32)
    b = rng.random((5, 7, 1), dtype=np.float32)
    b[0, 0, 0] = 0.0
    out = RatioImage().compute(a=Image(a), b=Image(b)).pixels
    np.testing.assert_array_equal(out, _closed_form(a, np.repeat(b, 3, -1), 1e-4))


def test_inputs_that_cannot_be_divided_name_port_b():
    from graphkit import BadInput
    from graphkit.contract import compute_checked

    a = Image(np.ones((4, 5, 3), np.float32))
    with pytest.raises(BadInput) as e:  # the size is declared (same_size_as): checked before compute
        compute_checked(RatioImage(), a=a, b=Image(np.ones((4, 6, 3), np.float32)))
    assert e.value.port == "b" and e.value.message == "image sizes differ: a is 5×4×3, b is 6×4×3"  # width×height×channels
    with pytest.raises(BadInput) as e:
        compute_checked(RatioImage(), a=a, b=Image(np.ones((4, 5, 2), np.float32)))
    assert e.value.port == "b" and e.value.message == "b has 2 channels; it needs 1 or 3 (as a)"
