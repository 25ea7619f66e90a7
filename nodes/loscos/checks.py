"""The node-specific input checks several Loscos nodes share, each worded once.

What a port declaration says (a photo's channels, a photo the size of the camera) is declared
on the port instead (docs/contract.md); these are the rules no declaration expresses: RGB
values in params and scene files, a perspective camera, a photo the size of a projection.
"""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Camera, Image


def _shown(value) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def _rgb(value) -> np.ndarray | None:
    """``value`` as 3 finite numbers, or None."""
    try:
        v = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        return None
    return v if v.shape == (3,) and np.all(np.isfinite(v)) else None


def emittance(value, port: str, who: str, alternative: str = "") -> np.ndarray:
    """``value`` as 3 finite RGB emittances ≥ 0 (W/m²), else BadInput naming ``who``."""
    e = _rgb(value)
    if e is None or np.any(e < 0):
        raise BadInput(port, f"{who}: emittance must be 3 finite values ≥ 0 (W/m²){alternative}, "
                             f"got {_shown(value)}")
    return e


def reflectance(value, port: str, who: str = "") -> np.ndarray:
    """``value`` as 3 finite diffuse albedos in [0, 1), else BadInput (naming ``who`` if given)."""
    r = _rgb(value)
    if r is None or np.any(r < 0) or np.any(r >= 1):
        raise BadInput(port, f"{who + ': ' if who else ''}reflectance must be 3 finite values in "
                             f"[0, 1) (diffuse albedo), got {_shown(value)}")
    return r


def pinhole(camera: Camera, port: str, needs: str) -> None:
    """BadInput unless ``camera`` is a perspective one (``needs``: what needs it)."""
    if camera.orthographic:
        raise BadInput(port, f"{needs} the photograph's perspective (pinhole) camera; this camera "
                             "is orthographic")


def photo_fits(photo: Image, projection) -> None:
    """BadInput unless ``photo`` has the size of the camera ``projection`` was made with."""
    if photo.pixels.shape[:2] != projection.pix_poly.shape:
        h, w = projection.pix_poly.shape
        raise BadInput("photo", f"photo is {photo.width}×{photo.height} but the projection's "
                                f"camera is {w}×{h}")
