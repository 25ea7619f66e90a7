"""LoadEnvironment: an equirectangular HDR environment map (``.exr`` / ``.hdr``) through
OpenImageIO, and the frame that says where its directions point.

Map convention (the common latitude–longitude panorama, as Mitsuba's ``envmap`` and Blender
read it): pixel (x, y) of a W×H map (W = 2H) has u = (x + ½)/W, v = (y + ½)/H, polar angle
θ = π·v from the map's *up* (top row: straight up) and azimuth φ = 2π·(u − ½); its direction
(towards the light) is  sin θ sin φ · right + cos θ · up + sin θ cos φ · centre.  So the
map's centre column looks along ``centre``, the column a quarter to its right along ``right``,
and the left and right edges along −``centre``.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict

from graphkit import BadInput, Camera, Field, Image, In, InputFile, Node, Out

from .builtin import BuiltinFiles
from .images import read_image_info

HDR_FORMATS = ("half", "float", "double")


class EnvironmentFrame(BaseModel):
    """Where an equirectangular map's axes point in the world frame (unit vectors): its
    ``centre`` column, its ``right`` (a quarter turn right of the centre) and its ``up`` (the
    top row)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    right: tuple[float, float, float] = (1.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, -1.0, 0.0)
    centre: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def matrix(self) -> np.ndarray:
        """3×3, columns right, up, centre: map-local (right, up, centre) → world."""
        return np.stack([self.right, self.up, self.centre], 1).astype(np.float64)


def local_directions(h: int, w: int) -> np.ndarray:
    """H×W×3 unit directions of the pixel centres in the map's own axes (right, up, centre)."""
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = 2 * np.pi * ((np.arange(w) + 0.5) / w - 0.5)
    st = np.sin(th)[:, None]
    return np.stack([st * np.sin(ph)[None, :], np.broadcast_to(np.cos(th)[:, None], (h, w)),
                     st * np.cos(ph)[None, :]], -1)


def solid_angles(h: int, w: int) -> np.ndarray:
    """H×1 solid angle (sr) of one pixel of each row (exact: they sum to 4π)."""
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    return ((edges[:-1] - edges[1:]) * 2 * np.pi / w)[:, None]


def check_equirect(px: np.ndarray, port: str, what: str) -> None:
    """BadInput unless ``px`` (H×W×C) is a 2:1 map of at least 3 channels, finite and ≥ 0."""
    h, w = px.shape[:2]
    if w != 2 * h:
        raise BadInput(port, f"{what} is {w}×{h}: an equirectangular map is twice as wide as high (2:1)")
    if px.shape[2] < 3:
        raise BadInput(port, f"{what} has {px.shape[2]} channel(s): an environment map needs RGB")
    nan = int(np.isnan(px).sum())
    inf = int(np.isinf(px).sum())
    neg = int((px < 0).sum())
    if nan or inf or neg:
        raise BadInput(port, f"{what} holds {nan} NaN, {inf} Inf and {neg} negative values: radiance "
                             "must be finite and ≥ 0 (repair or re-export the map)")


class LoadEnvironment(BuiltinFiles, Node):
    """Read an equirectangular HDR environment map (OpenEXR or Radiance ``.hdr``, linear RGB
    radiance) and say where it points.

    Orientation: pixel (x, y) of the W×H map has u = (x + ½)/W, v = (y + ½)/H, θ = π·v,
    φ = 2π·(u − ½), and looks towards sin θ sin φ · right + cos θ · up + sin θ cos φ · centre:
    the centre column looks along ``centre``, the top row straight ``up``, the column a
    quarter to the right of the centre along ``right`` (Mitsuba's ``envmap`` and Blender read
    maps so, here with to_world columns −right, up, centre).  Without a ``camera`` the frame is
    the world's with OpenCV axes: centre = +z (forward), up = −y, right = +x.  With the face
    ``camera`` connected they are that camera's: the map's centre is what the camera sees
    behind the face, its left and right edges are behind the camera (the light that falls on
    the face's front), its top is the camera's up.  ``rotation_deg`` turns the environment
    about the up axis: the map's centre moves from ``centre`` towards ``right`` by that angle
    (so a light in the map turns towards the image's right, seen from the camera's side of a
    light behind the face).

    Refused (exit 2, nothing written): a file that is not a float (HDR) image, a map that is
    not 2:1, one with fewer than 3 channels, NaN, Inf or negative values.
    """

    builtin_what = "environment map"
    version = "1"
    inputs = {"camera": In(Camera, "express the map's axes in this camera's frame (the face camera)",
                           optional=True)}
    outputs = {"image": Out(Image, "the map, RGB radiance (H×2H, as stored)"),
               "frame": Out(EnvironmentFrame, "where the map's centre, right and up point (world)")}

    class Params(Node.Params):
        path: InputFile = Field(description="equirectangular .exr or .hdr, relative to the graph file, "
                                            "or builtin:envmaps/NAME.exr")
        rotation_deg: float = Field(0.0, ge=-360, le=360, description="turn the environment about the up "
                                                                     "axis (degrees, + = centre towards right)")
        scale: float = Field(1.0, gt=0, description="multiplier on the radiance")

    def compute(self, camera: Camera | None = None):
        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        px = read_hdr(path)
        check_equirect(px, "path", path)
        px = np.ascontiguousarray(px[:, :, :3] * np.float32(self.params.scale), np.float32)
        return {"image": Image(px), "frame": self.frame(camera)}

    def frame(self, camera: Camera | None) -> EnvironmentFrame:
        axes = np.eye(3) if camera is None else camera.rotation  # rows: the camera's x, y, z in world
        right, up, centre = axes[0], -axes[1], axes[2]
        a = np.radians(self.params.rotation_deg)
        right, centre = np.cos(a) * right - np.sin(a) * centre, np.cos(a) * centre + np.sin(a) * right
        t = lambda v: tuple(float(x) + 0.0 for x in v)  # noqa: E731  (+ 0.0: no −0.0)
        return EnvironmentFrame(right=t(right), up=t(up), centre=t(centre))

    @classmethod
    def examples(cls):
        return [({"path": "builtin:envmaps/window.exr"}, {}),
                ({"path": "builtin:envmaps/studio.exr", "rotation_deg": 90.0},
                 {"camera": Camera(width=32, height=32, fx=40, fy=40, cx=16, cy=16)})]


def read_hdr(path: str, port: str = "path") -> np.ndarray:
    """The float pixels of an HDR file (H×W×C float32); BadInput when the file stores integers
    (an 8/16-bit PNG, JPEG or TIFF is display-referred, not radiance)."""
    import OpenImageIO as oiio

    from graphkit.paths import input_file_problem

    problem = input_file_problem(path)
    if problem:
        raise BadInput(port, problem)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise BadInput(port, f"cannot read {path} as an image: {(oiio.geterror() or 'unknown format').strip()}")
    fmt = str(inp.spec().format)
    inp.close()
    if fmt not in HDR_FORMATS:
        raise BadInput(port, f"{path} stores {fmt} values, not HDR radiance: give a float OpenEXR or "
                             "Radiance .hdr equirectangular map")
    px, _, _, _ = read_image_info(path, port)
    return px
