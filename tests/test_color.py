"""nodes.common.color's local CIELAB gives colour-science's values, to the last bits: the two
multiply the sRGB → XYZ matrices in another order of BLAS calls, which round alike on an AVX-512
machine (the same bits there) and up to 1.2e-13 apart (L*, a*, b* ≈ 0–100) on an AVX2 one."""
import warnings

import numpy as np

from nodes.common.color import linear_srgb_to_lab, linear_srgb_to_xyz


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
