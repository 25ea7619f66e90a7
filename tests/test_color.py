"""nodes.common.color's local CIELAB gives colour-science's values, to the last bits: the two
multiply the sRGB → XYZ matrices in another order of BLAS calls, which round alike on an AVX-512
machine (the same bits there) and up to 1.2e-13 apart (L*, a*, b* ≈ 0–100) on an AVX2 one."""
import warnings

import numpy as np

from nodes.common.color import (channel_max, channel_min, linear_srgb_to_lab, linear_srgb_to_xyz, linear_to_codes, linear_to_srgb,
                                srgb_codes_to_linear, srgb_to_linear)


def test_lab_same_bits_as_colour():
    warnings.filterwarnings("ignore", message='"Matplotlib" related API features')
    import colour

    rng = np.random.default_rng(3)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    for x in (rng.random((50000, 3)) * 2, rng.random((5000, 3)) ** 6, rng.random((7, 4, 3)),
              np.zeros((2, 3)), np.eye(3)):
        want = colour.XYZ_to_Lab(linear_srgb_to_xyz(x), white)
        got = linear_srgb_to_lab(x)
        assert got.shape == want.shape
        assert np.abs(got - want).max() <= 1e-12, np.abs(got - want).max()


def _values():
    rng = np.random.default_rng(5)
    edge = np.array([0.0, -0.0, 1e-12, 0.0031308, np.nextafter(0.0031308, 1), 0.04045, 0.0031308 * 12.92,
                     np.nextafter(0.0031308 * 12.92, 1), 0.5, 1.0, 1.5, 40.0, -0.01, -2.0])
    return [edge, rng.random(100000), rng.random(100000) ** 8, rng.random((30, 40, 3)) * 3,
            rng.random((7, 5, 3)).astype(np.float32), (rng.random(5000) * 2 - 1).astype(np.float32)]


def test_srgb_transfer_functions_same_bits_as_colour():
    """The sRGB EOTF and its inverse, written out for speed, give colour-science's values to the
    last bit on every kind of input (both segments, the knee, negatives, float32 and float64)."""
    warnings.filterwarnings("ignore", message='"Matplotlib" related API features')
    import colour

    for x in _values():
        for ours, theirs in ((srgb_to_linear, colour.models.eotf_sRGB),
                             (linear_to_srgb, colour.models.eotf_inverse_sRGB)):
            want = np.asarray(theirs(np.asarray(x, np.float64)), np.float32)
            got = ours(x)
            assert got.dtype == np.float32 and got.shape == want.shape
            assert np.array_equal(got, want, equal_nan=True), (ours.__name__, np.abs(got - want).max())


def test_srgb_codes_decode_as_colour():
    """Every 8- and 16-bit code decodes to colour-science's EOTF of code / (2**bits − 1)."""
    warnings.filterwarnings("ignore", message='"Matplotlib" related API features')
    import colour

    for bits, dtype in ((8, np.uint8), (16, np.uint16)):
        codes = np.arange(1 << bits).astype(dtype).reshape(-1, 1)
        top = np.float32((1 << bits) - 1)
        want = np.asarray(colour.models.eotf_sRGB(np.asarray(codes.astype(np.float32) / top, np.float64)),
                          np.float32)
        got = srgb_codes_to_linear(codes, bits)
        assert got.dtype == np.float32 and np.array_equal(got, want)
    assert srgb_codes_to_linear(np.array([[[0, 255, 128]]], np.uint8)).shape == (1, 1, 3)


def test_codes_as_colour_encodes_and_rounds():
    """linear_to_codes gives the codes of colour-science's inverse EOTF, clipped and rounded —
    8 and 16 bits, sRGB or linear (masks), float32 and float64 in, over the chunk size."""
    warnings.filterwarnings("ignore", message='"Matplotlib" related API features')
    import colour

    rng = np.random.default_rng(8)
    xs = _values() + [rng.random((700, 300, 3)) * 1.2 - 0.1]
    for x in xs:
        lin = np.clip(x, 0, None)
        for srgb in (True, False):
            enc = np.asarray(colour.models.eotf_inverse_sRGB(np.asarray(lin, np.float64)), np.float32) if srgb else lin
            enc = np.clip(enc, 0.0, 1.0)
            for bits, top, dtype in ((8, 255, np.uint8), (16, 65535, np.uint16)):
                want = np.round(enc * top).astype(dtype)
                got = linear_to_codes(x, bits, srgb)
                assert got.dtype == dtype and np.array_equal(got, want), (bits, srgb, x.dtype)


def test_channel_max_and_min_are_numpys():
    """channel_max / channel_min: numpy's max / min over the last axis, value for value (1, 3 and 4
    channels, float32 and float64, NaN propagated, one pixel and a photo), in the input's type."""
    rng = np.random.default_rng(9)
    for shape in ((1, 1, 3), (5, 7, 1), (300, 200, 3), (40, 30, 4), (1000, 3)):
        for dtype in (np.float32, np.float64):
            x = (rng.random(shape) * 4 - 1).astype(dtype)
            x.reshape(-1)[::97] = np.nan
            for got, want in ((channel_max(x), x.max(-1)), (channel_min(x), x.min(-1))):
                assert got.dtype == dtype and got.shape == want.shape
                assert np.array_equal(got, want, equal_nan=True), (shape, dtype)
