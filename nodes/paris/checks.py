"""Input checks several Paris nodes share that no port constraint expresses (docs/contract.md):
what is declared on the ports (sizes, finite mesh vertices, …) the engine checks before compute."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Image


def check_mesh(mesh, port: str = "mesh") -> None:
    """BadInput unless the mesh has triangles (finite vertices are declared on the mesh port:
    ``In(Mesh, ..., finite=True)``)."""
    if mesh is None or len(mesh.faces) == 0:
        raise BadInput(port, "the mesh has no triangles")


def check_rgb(image: Image, port: str, grey: bool = False) -> None:
    """BadInput unless ``image`` has colour: 3 channels or more (the first three are RGB), or
    one when ``grey`` (taken as R = G = B).  (A ``channels=`` declaration lists exact counts.)"""
    if image.channels < 3 and not (grey and image.channels == 1):
        need = "1 or at least 3" if grey else "at least 3"
        raise BadInput(port, f"needs an RGB image ({need} channels), got {image.channels}")


def rgb_pixels(image: Image, port: str, grey: bool = False, float64: bool = True) -> np.ndarray:
    """The image's RGB as float64 H×W×3 (:func:`check_rgb`; a grey image repeated), refused
    when a value is NaN or infinite.  ``float64=False``: in the image's own float type, not
    copied (a caller that reads a many-megapixel photo only in part converts that part)."""
    from graphkit.types import finite_or_message

    check_rgb(image, port, grey)
    px = np.asarray(image.pixels)
    if float64 or px.dtype.kind != "f":
        px = np.asarray(px, np.float64)
    px = np.repeat(px, 3, 2) if px.shape[2] == 1 else px[..., :3]
    problem = finite_or_message(px)
    if problem:
        raise BadInput(port, f"the image holds {problem}")
    return px


def check_lit(diffuse: np.ndarray, port: str, light: str, pixels: str) -> None:
    """BadInput unless the light (described by ``light``) lights one of the pixels (its
    diffuse term ``diffuse`` > 0 at one of them, described by ``pixels``)."""
    if not (diffuse > 0).any():
        raise BadInput(port, f"{light} is behind the face: it lights none of the {pixels}")


def unit_direction(d, port: str, what: str = "the light direction") -> np.ndarray:
    """The 3-vector ``d`` divided by its length (float64); BadInput when it is zero or not
    finite (a Light's direction is not checked by its type)."""
    d = np.asarray(d, np.float64)
    n = np.linalg.norm(d)
    if not (np.isfinite(d).all() and n > 0):
        raise BadInput(port, f"{what} {tuple(float(x) for x in d)} is zero or not finite")
    return d / n
