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


def linear_srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB → CIE L*a*b* (D65 white)."""
    import colour

    xyz = linear_srgb_to_xyz(rgb)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
