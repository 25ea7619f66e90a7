"""Images for the page: linear float pixels → 8-bit sRGB PNG, with an exposure in stops.

HDR values (EXR outputs) are shown as a camera would: scaled by 2**exposure, clipped to
[0, 1] and encoded with the sRGB transfer function (IEC 61966-2-1).  One-channel images and
masks are grey; images with more than three channels show their first three.
"""
from __future__ import annotations

import numpy as np

_N = 4096
_LUT = None


def _lut() -> np.ndarray:
    global _LUT
    if _LUT is None:
        x = np.linspace(0.0, 1.0, _N, dtype=np.float64)
        srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
        _LUT = np.clip(np.round(srgb * 255.0), 0, 255).astype(np.uint8)
    return _LUT


def display_rgb(pixels: np.ndarray, exposure: float = 0.0, srgb_encoded: bool = False) -> np.ndarray:
    """H×W×3 uint8 sRGB of linear ``pixels`` (H×W, H×W×1, H×W×3 or more channels)."""
    a = np.asarray(pixels, np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    elif a.shape[2] == 2:
        a = np.concatenate([a, np.zeros_like(a[:, :, :1])], axis=2)
    else:
        a = a[:, :, :3]
    scale = np.float32(2.0 ** float(exposure))
    if srgb_encoded:
        return np.clip(np.nan_to_num(a * scale) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    # index of the LUT: x·2^e·(N−1) + ½, NaN and −inf → 0, +inf → N−1 (fmax/fmin drop a NaN)
    t = np.multiply(a, scale, dtype=np.float32)
    t *= np.float32(_N - 1)
    t += np.float32(0.5)
    np.fmax(t, np.float32(0), out=t)
    np.fmin(t, np.float32(_N - 1), out=t)
    return np.take(_lut(), t.astype(np.uint16))


def png(rgb8: np.ndarray, level: int = 1) -> bytes:
    """PNG bytes of an H×W×3 uint8 sRGB image (OpenCV's encoder).  ``level`` 1: zlib's fastest
    compression over the "up" filter (as small as the adaptive filters here, twice as fast);
    0: no compression and no filter (~10× faster again, ~5× the bytes: for the loopback)."""
    import cv2

    flags = [cv2.IMWRITE_PNG_COMPRESSION, int(level),
             cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP if level else cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb8), cv2.COLOR_RGB2BGR), flags)
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def rgba(rgb8: np.ndarray) -> bytes:
    """The H×W×4 RGBA bytes (alpha 255) of an H×W×3 uint8 image: what a page's canvas takes
    as it is (ImageData), with no decoding at all."""
    h, w = rgb8.shape[:2]
    out = np.empty((h, w, 4), np.uint8)
    out[:, :, :3] = rgb8
    out[:, :, 3] = 255
    return out.tobytes()


def preview_png(ptype_name: str, value, exposure: float = 0.0, max_side: int = 0, level: int = 1) -> bytes:
    """PNG of an Image or Mask value for the page (``level``: see :func:`png`)."""
    return png(preview_rgb(ptype_name, value, exposure, max_side), level)


def preview_rgb(ptype_name: str, value, exposure: float = 0.0, max_side: int = 0) -> np.ndarray:
    """H×W×3 uint8 sRGB of an Image or Mask value as the page shows it (``max_side``: the
    longer side at most, 0 for the value's own size)."""
    if ptype_name == "Mask":
        px, enc = value.alpha, True  # weights in [0, 1]: shown as they are
    else:
        px = value.pixels
        enc = str(getattr(value, "colorspace", "lin_srgb")).lower() in ("srgb", "srgb_rec709_scene")
    if max_side and max(px.shape[:2]) > max_side:
        import cv2

        k = max_side / max(px.shape[:2])
        size = (max(1, round(px.shape[1] * k)), max(1, round(px.shape[0] * k)))
        px = cv2.resize(np.ascontiguousarray(px, np.float32), size, interpolation=cv2.INTER_AREA)
    return display_rgb(px, exposure, srgb_encoded=enc)
