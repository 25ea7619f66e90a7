"""Colour conversions used across the node library, through colour-science.

Images inside graphs are linear RGB with sRGB/Rec.709 primaries (tag ``lin_srgb``); these
helpers decode and encode at the edges (file I/O) and convert for perceptual distances.
"""
from __future__ import annotations

import warnings

import numpy as np

# colour-science warns at import when matplotlib (plotting only) is absent; we never plot with it.
warnings.filterwarnings("ignore", message='"Matplotlib" related API features are not available')


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (IEC 61966-2-1 EOTF), float32."""
    import colour

    return np.asarray(colour.models.eotf_sRGB(np.asarray(x, np.float64)), np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values → sRGB-encoded (inverse EOTF), float32; values are not clipped."""
    import colour

    return np.asarray(colour.models.eotf_inverse_sRGB(np.asarray(x, np.float64)), np.float32)


def linear_srgb_to_xyz(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB → CIE XYZ (D65)."""
    import colour

    cs = colour.RGB_COLOURSPACES["sRGB"]
    return colour.RGB_to_XYZ(rgb, cs, apply_cctf_decoding=False)


def linear_srgb_to_luv(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB → CIE L*u*v* (D65 white)."""
    import colour

    xyz = linear_srgb_to_xyz(rgb)
    return colour.XYZ_to_Luv(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


#: colour-science's sRGB RGB→XYZ matrix and the CAT02 D65→D65 matrix its RGB_to_XYZ applies
#: after it (identity to 1e-16, kept so that the bits match), and the D65 white's XYZ
_SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                         [0.0193, 0.1192, 0.9505]])
_CAT02_D65 = np.array([[1.0, -2.925337592710602e-17, -2.0424934209769367e-17],
                       [1.865516512262643e-17, 1.0, -6.012863655103287e-19],
                       [-1.1925326645651568e-18, -6.805220268068795e-19, 1.0]])
_D65_XYZ = np.array([0.9504559270516716, 1.0, 1.0890577507598784])


def linear_srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB → CIE L*a*b* (D65 white): colour-science's ``XYZ_to_Lab(RGB_to_XYZ(rgb))``
    step for step (within 1e-12 of it, tests/test_color.py: the matrix products round alike on
    some CPUs, not all), without importing colour (≈ 1 s)."""
    xyz = np.matmul(_CAT02_D65, np.matmul(_SRGB_TO_XYZ, np.asarray(rgb, np.float64)[..., None]))
    fx, fy, fz = (_lab_f(xyz[..., i, 0] / _D65_XYZ[i]) for i in range(3))
    return np.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)], -1)


def _lab_f(t: np.ndarray) -> np.ndarray:
    """CIE 1976's intermediate lightness function of Y/Y_n."""
    return np.where(t > (24 / 116) ** 3, np.sign(t) * np.abs(t) ** (1 / 3), (841 / 108) * t + 16 / 116)
