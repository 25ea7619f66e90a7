"""LoadPhoto — an 8-bit phone or camera photo (JPEG/PNG) as a linear image, explicitly."""
from __future__ import annotations

from typing import Optional

import numpy as np
from pydantic import field_validator

from graphkit import BadInput, Field, Image, InputFile, Mask, Node, Out
from graphkit.paths import input_file_problem

from .builtin import BuiltinFiles

CLIP_CODE = 255


def read_photo(path: str, port: str = "path") -> tuple[np.ndarray, dict]:
    """An 8-bit RGB photo's codes (H×W×3 uint8, EXIF orientation applied) and what the file
    says about itself (``orientation``, ``profile``).  BadInput naming ``port`` for a file that is
    not an 8-bit RGB / grey photo: CMYK, 16-bit, float, an unreadable file."""
    import OpenImageIO as oiio

    problem = input_file_problem(path)
    if problem:
        raise BadInput(port, problem)
    buf = oiio.ImageBuf(path)
    spec = buf.spec()
    if buf.has_error or spec.nchannels == 0:
        raise BadInput(port, f"cannot read image {path}: {(buf.geterror() or 'unknown format').strip()}")
    space = " ".join(str(spec.getattribute(a) or "") for a in ("jpeg:ColorSpace", "oiio:ColorSpace"))
    if "CMYK" in space.upper() or spec.nchannels == 4 and spec.alpha_channel < 0:
        raise BadInput(port, f"{path} is a CMYK image: LoadPhoto reads RGB photos; convert it to "
                             "sRGB (e.g. `magick in.jpg -colorspace sRGB out.jpg`) and load that")
    fmt = str(spec.format)
    if fmt != "uint8":
        raise BadInput(port, f"{path} holds {fmt} values ({spec.get_int_attribute('oiio:BitsPerSample', 0) or '?'}"
                             " bits): LoadPhoto reads 8-bit sRGB photos; load 16-bit or float files with "
                             "LoadImage (colorspace: srgb or linear)")
    orientation = int(spec.get_int_attribute("Orientation", 1))
    if orientation != 1:
        buf = oiio.ImageBufAlgo.reorient(buf)
    codes = np.asarray(buf.get_pixels(oiio.UINT8), np.uint8)
    if codes.ndim == 2:
        codes = codes[:, :, None]
    colour = [i for i in range(codes.shape[2]) if i != spec.alpha_channel]
    if len(colour) == 1:
        colour = colour * 3
    if len(colour) != 3:
        raise BadInput(port, f"{path} has {len(colour)} colour channels: LoadPhoto reads RGB or grey photos")
    profile = str(spec.getattribute("ICCProfile:profile_description") or "")
    return np.ascontiguousarray(codes[:, :, colour]), {"orientation": orientation, "profile": profile}


class LoadPhoto(BuiltinFiles, Node):
    """Read an 8-bit sRGB photo (JPEG/PNG from a phone or camera) into a linear float32 Image.

    * The EXIF orientation is applied (a portrait shot with the phone on its side comes out
      upright); the run says so when the file was turned.
    * The 8-bit codes are linearised explicitly: the sRGB EOTF (IEC 61966-2-1, through
      colour-science) by default, or the camera's response curve given as ``response``: 256
      linear values, one per code, non-decreasing.  A file with an ICC profile other than sRGB
      (Display P3, Adobe RGB) is read as sRGB, and the run says so.
    * ``clipped``: the pixels at code 255 in any channel (the sensor or the JPEG saturated there:
      their true value is unknown).  Connect it to SkinSegment's ``exclude`` so the fits leave
      them out; their count is in the run's notices.
    * Refused (exit 2, naming the port): CMYK files, 16-bit or float files (LoadImage reads
      those), files with two colour channels, unreadable files.
    """

    builtin_what = "image"
    version = "1"
    outputs = {"image": Out(Image, "the photo, linear RGB"),
               "clipped": Out(Mask, "pixels at code 255 in any channel (unknown true value)")}

    class Params(Node.Params):
        path: InputFile = Field(description="JPEG or PNG, relative to the graph file, or builtin:NAME")
        response: Optional[list[float]] = Field(
            None, description="the camera's response: 256 linear values for codes 0…255 (default: the sRGB EOTF)")

        @field_validator("response")
        @classmethod
        def _curve(cls, v):
            if v is None:
                return v
            a = np.asarray(v, float)
            if a.shape != (256,) or not np.isfinite(a).all() or (np.diff(a) < 0).any() or a[0] < 0:
                raise ValueError("response must be 256 finite, non-negative, non-decreasing linear values "
                                 "(one per 8-bit code)")
            return v

    def compute(self):
        from nodes.common.color import srgb_codes_to_linear

        p = self.params
        path = self.resolve_file("path", p.path, self.ctx.base_dir)
        codes, info = read_photo(path)
        if info["orientation"] != 1:
            self.ctx.notice(f"EXIF orientation {info['orientation']}: the photo was turned upright "
                            f"({codes.shape[1]}×{codes.shape[0]})")
        if info["profile"] and "srgb" not in info["profile"].lower():
            self.ctx.notice(f"ICC profile '{info['profile']}' is read as sRGB (colours may shift slightly)")
        if p.response is not None:
            lin = np.asarray(p.response, np.float32)[codes]
        else:
            lin = srgb_codes_to_linear(codes)
        clipped = (codes == CLIP_CODE).any(axis=2)
        n = int(clipped.sum())
        if n:
            self.ctx.notice(f"{n} pixels ({100.0 * n / clipped.size:.2f} %) are clipped (code 255 in a channel): "
                            "output 'clipped' (in SkinSegment's exclude, as graphs/phone_relight.yaml has it, "
                            "they are left out of the skin and so of the fits)")
        return {"image": Image(np.ascontiguousarray(lin, np.float32), "lin_srgb"),
                "clipped": Mask(clipped.astype(np.float32))}
