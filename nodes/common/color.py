"""Colour conversions used across the node library: colour-science's, or (where its wrappers
cost several times the arithmetic on a many-megapixel photo) its formulas step for step, with
the same bits (tests/test_color.py holds them to colour-science's).

Images inside graphs are linear RGB with sRGB/Rec.709 primaries (tag ``lin_srgb``); these
helpers decode and encode at the edges (file I/O) and convert for perceptual distances.
"""
from __future__ import annotations

import warnings

import numpy as np

# colour-science warns at import when matplotlib (plotting only) is absent; we never plot with it.
warnings.filterwarnings("ignore", message='"Matplotlib" related API features are not available')


#: colour-science's eotf_sRGB switches to the linear segment at eotf_inverse_sRGB(0.0031308)
_V_KNEE = 0.0031308 * 12.92
#: elements converted at a time: float64 temporaries of 512 KiB stay in the cache and in the heap
#: (a 12-megapixel image's whole-size temporaries are 290 MB each, every one fresh pages)
_CHUNK = 1 << 16


def _elementwise(fn, x, dtype=np.float32) -> np.ndarray:
    """fn (element by element) over x's values in chunks of ``_CHUNK`` → ``dtype`` of x's shape."""
    x = np.asarray(x)
    flat = x.reshape(-1)
    out = np.empty(flat.shape, dtype)
    with np.errstate(invalid="ignore"):
        for i in range(0, flat.size, _CHUNK):
            out[i:i + _CHUNK] = fn(flat[i:i + _CHUNK])
    return out.reshape(x.shape)


def _eotf(v):
    v = v.astype(np.float64)
    return np.where(_V_KNEE >= v, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def _eotf_inverse(v):
    v = v.astype(np.float64)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def channel_max(px: np.ndarray) -> np.ndarray:
    """Each pixel's largest channel (… × C → …, in the array's own type): ``px.max(-1)``, the
    same values, 8× faster on a photo (numpy reduces a 3-long last axis pixel by pixel, 0.87 s
    for a 21-megapixel float32 image; ``np.maximum`` runs over whole channel planes, 0.10 s)."""
    return _channel_reduce(np.maximum, px)


def channel_min(px: np.ndarray) -> np.ndarray:
    """Each pixel's smallest channel: ``px.min(-1)``, as :func:`channel_max`."""
    return _channel_reduce(np.minimum, px)


def _channel_reduce(op, px):
    px = np.asarray(px)
    if px.shape[-1] == 1:
        return px[..., 0].copy()
    out = op(px[..., 0], px[..., 1])
    for c in range(2, px.shape[-1]):
        op(out, px[..., c], out=out)
    return out


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (IEC 61966-2-1 EOTF), float32.

    colour-science's ``eotf_sRGB`` step for step (the same bits, tests/test_color.py), without
    its domain-scale and safe-power wrappers, which cost 5 × the arithmetic on a photo (4.2 s
    against 0.8 s for a 12-megapixel one), in chunks.  8-bit codes: :func:`srgb_codes_to_linear`."""
    return _elementwise(_eotf, x)


def srgb_codes_to_linear(codes: np.ndarray, bits: int = 8) -> np.ndarray:
    """Integer sRGB codes (0 … 2**bits − 1) → linear float32: :func:`srgb_to_linear` of
    ``codes / (2**bits − 1)`` (in float32, as a decoder divides), through a table of every code."""
    top = (1 << bits) - 1
    table = srgb_to_linear(np.arange(top + 1, dtype=np.float32) / np.float32(top))
    return table[np.asarray(codes)]


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values → sRGB-encoded (inverse EOTF), float32; values are not clipped.

    colour-science's ``eotf_inverse_sRGB`` step for step (the same bits, tests/test_color.py),
    in chunks: 0.4 s against colour's 4.9 s for a 12-megapixel image."""
    return _elementwise(_eotf_inverse, x)


def linear_to_codes(x: np.ndarray, bits: int = 8, srgb: bool = True) -> np.ndarray:
    """Linear values → integer codes of a file or a display (uint8, or uint16 for ``bits`` 16):
    clipped below at 0, sRGB-encoded (:func:`linear_to_srgb`; not with ``srgb=False``: masks),
    clipped to [0, 1], scaled and rounded — ``np.round(np.clip(linear_to_srgb(np.clip(x, 0,
    None)), 0, 1) * 255)``, the same bits, in chunks (one pass over a 12-megapixel image instead
    of six whole-size temporaries)."""
    dtype, top = (np.uint16, 65535) if bits == 16 else (np.uint8, 255)

    def codes(v):
        v = np.clip(v, 0, None)
        if srgb:
            v = _eotf_inverse(v).astype(np.float32)
        return np.round(np.clip(v, 0.0, 1.0) * top).astype(dtype)

    return _elementwise(codes, x, dtype)


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
