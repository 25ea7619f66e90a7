"""LoadImage / SaveImage through OpenImageIO (PNG, JPEG, EXR, HDR, TIFF, …)."""
from __future__ import annotations

import os
import tempfile
from pathlib import PurePosixPath
from typing import Literal

import numpy as np
from pydantic import field_validator

from graphkit import BadInput, Field, File, Image, In, InputFile, Mask, Node, OutputPath
from graphkit.paths import input_file_problem, safe_relpath

from .builtin import BuiltinFiles

INTEGER_FORMATS = ("uint8", "uint16", "int8", "int16", "uint32", "int32")
WRITE_EXTS = (".exr", ".png", ".jpg", ".jpeg", ".hdr", ".tif", ".tiff")
HALF_MAX = 65504.0  # largest finite IEEE half float
FLOAT32_MAX = float(np.finfo(np.float32).max)


def read_image_info(path: str, port: str = "path") -> tuple[np.ndarray, bool, tuple[str, ...], int]:
    """Read any OIIO-readable file → (float32 H×W×C array, whether it is integer-encoded,
    channel names, index of the alpha channel or -1).  Colour is returned as the file stores
    it: a PNG's or TIFF's colour is not multiplied by its alpha (OpenImageIO's default)."""
    import OpenImageIO as oiio

    problem = input_file_problem(path)
    if problem:
        raise BadInput(port, problem)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # PNG/TIFF colour as stored, not premultiplied
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        msg = oiio.geterror() or "unknown format"
        raise BadInput(port, f"cannot read image {path}: {msg.strip()}")
    try:
        spec = inp.spec()
        px = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if px is None:
            raise BadInput(port, f"cannot read image {path}: {inp.geterror().strip() or 'read failed'}")
        integer = str(spec.format) in INTEGER_FORMATS
        names, alpha = tuple(spec.channelnames), int(spec.alpha_channel)
    finally:
        inp.close()
    px = np.asarray(px, dtype=np.float32)
    if px.ndim == 2:
        px = px[:, :, None]
    return px, integer, names, alpha


def read_image(path: str, port: str = "path") -> tuple[np.ndarray, bool]:
    """Read any OIIO-readable file → (float32 H×W×C array, whether it is integer-encoded)."""
    px, integer, _, _ = read_image_info(path, port)
    return px, integer


def encode_image(pixels: np.ndarray, ext: str, bits: int = 16, metadata: dict | None = None,
                 srgb: bool = True) -> bytes:
    """Encode linear float pixels as a file's bytes: EXR/HDR/TIFF keep linear floats (EXR: half
    for ``bits`` 16, float for 32); PNG/JPEG are sRGB-encoded (or not, with ``srgb=False``:
    masks), clipped to [0, 1] and rounded to 8 (or 16, PNG) bits.  A half EXR turns values
    above 65504 into Inf: callers check the range first (SaveImage does)."""
    import OpenImageIO as oiio

    from nodes.common.color import linear_to_codes

    ext = ext.lower()
    h, w, c = pixels.shape
    if ext in (".png", ".jpg", ".jpeg"):
        b = 16 if ext == ".png" and bits == 16 else 8
        data, fmt = linear_to_codes(pixels, b, srgb), ("uint16" if b == 16 else "uint8")
    elif ext == ".exr":
        data, fmt = np.ascontiguousarray(pixels, np.float32), ("half" if bits == 16 else "float")
    else:
        data, fmt = np.ascontiguousarray(pixels, np.float32), "float"
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.attribute("Software", "relightkit graphkit")
    spec.attribute("DateTime", "")  # OpenEXR would stamp the clock: same inputs must give same bytes
    if ext == ".exr":
        spec.attribute("compression", "zip")
    for k, v in (metadata or {}).items():
        spec.attribute(k, str(v))
    with tempfile.TemporaryDirectory(prefix="graphkit-enc-") as d:
        path = os.path.join(d, "image" + ext)
        out = oiio.ImageOutput.create(path)
        if out is None:
            raise RuntimeError(f"OpenImageIO cannot write {ext}: {oiio.geterror()}")
        if not out.open(path, spec):
            raise RuntimeError(f"OpenImageIO cannot write {ext}: {out.geterror()}")
        ok = out.write_image(data)
        out.close()
        if not ok:
            raise RuntimeError(f"OpenImageIO failed writing {ext}: {out.geterror()}")
        with open(path, "rb") as f:
            return f.read()


class LoadImage(BuiltinFiles, Node):
    """Read an image file with OpenImageIO into a linear float32 Image.

    8/16-bit files (PNG, JPEG, TIFF) are sRGB-decoded to linear unless ``colorspace`` says
    otherwise (an alpha channel is never decoded, and colour is not premultiplied by it); float
    files (EXR, HDR) are taken as linear.
    An alpha channel (named so in the file, or the 4th of four) is dropped unless
    ``drop_alpha`` is false, so a grey + alpha file gives a one-channel image; a file with two
    colour channels (e.g. R, G) is refused.  ``builtin:astronaut`` names scikit-image's
    astronaut photograph, ``builtin:sample_capture/photo.exr`` a file of the Paris sample
    capture.  Files with NaN or Inf values are refused.
    """

    builtin_what = "image"
    version = "2"  # 2: alpha found by name (grey + alpha files), not sRGB-decoded, not premultiplied
    outputs = {"image": Image}

    class Params(Node.Params):
        path: InputFile = Field(description="image file, relative to the graph file, or builtin:NAME")
        colorspace: Literal["auto", "srgb", "linear"] = Field(
            "auto", description="encoding of the file's values: auto = sRGB for integer files, linear for float")
        drop_alpha: bool = Field(True, description="drop the alpha channel of RGBA / grey + alpha files")

    def compute(self):
        from graphkit.types import finite_or_message
        from nodes.common.color import srgb_to_linear

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        px, integer, names, alpha = read_image_info(path)
        if alpha < 0 and px.shape[2] == 4:
            alpha = 3  # RGBA without a channel named A (e.g. some TIFFs)
        colour = [i for i in range(px.shape[2]) if i != alpha]
        if len(colour) == 2:
            raise BadInput("path", f"{path} has two colour channels ({', '.join(names[i] for i in colour)}); "
                           "LoadImage reads grey (1), RGB (3) and RGBA (4) images, or grey + alpha")
        if self.params.drop_alpha and alpha >= 0:
            px, alpha = px[:, :, colour], -1
        bad = finite_or_message(px)
        if bad:
            raise BadInput("path", f"{path} holds {bad}")
        cs = self.params.colorspace
        if cs == "srgb" or (cs == "auto" and integer):
            if alpha < 0:
                px = srgb_to_linear(px)
            else:
                px = px.copy()
                px[:, :, colour] = srgb_to_linear(px[:, :, colour])
        return Image(np.ascontiguousarray(px, np.float32), "lin_srgb")


class SaveImage(Node):
    """Encode an Image (or a Mask, as a one-channel image) as a file in the run's output folder
    (EXR, PNG, JPEG, HDR, TIFF).

    PNG and JPEG hold [0, 1]: images are sRGB-encoded and clipped, masks written linearly (load
    them back with ``colorspace: linear``).  Float formats hold the values themselves, so a value
    outside the format's range is a decision, not a silent change: the default 16-bit (half)
    EXR tops out at 65504, above which a value would become Inf (and LoadImage would then refuse
    the file).  ``overflow`` says what to do with such values: ``refuse`` (the default: exit 2
    naming how many values are too large and the largest one), ``clamp`` (to ±65504), or
    ``float32`` (write this file as 32-bit float EXR instead).  NaN or Inf values are refused.

    The file carries provenance in its metadata: ``graphkit:key`` (the cache key of this
    result) and ``graphkit:recipe`` (digest of the part of the graph that produced it).
    """

    version = "3"  # 3: overflow checks, masks, exposure applied in float64 (2: no DateTime stamp)
    provenance = True
    inputs = {"image": In(Image, "the image to write", optional=True),
              "mask": In(Mask, "or a mask, written as a one-channel image", optional=True)}
    outputs = {"file": File}

    class Params(Node.Params):
        path: OutputPath = Field(description="file name inside --out, e.g. relit/front.exr; the extension picks the format")
        bits: Literal[8, 16, 32] = Field(16, description="EXR: 16 (half) or 32 (float); PNG: 8 or 16")
        exposure: float = Field(0.0, description="stops added before encoding")
        overflow: Literal["refuse", "clamp", "float32"] = Field(
            "refuse", description="values beyond a half EXR's ±65504 (or float32's range): refuse (exit 2), "
                                  "clamp to the largest value, or write the EXR as 32-bit float")

        @field_validator("path")
        @classmethod
        def _relative(cls, v: str) -> str:
            return safe_relpath(v, WRITE_EXTS)

    def compute(self, image: Image | None = None, mask: Mask | None = None):
        from graphkit.types import finite_or_message

        p = self.params
        if (image is None) == (mask is None):
            raise BadInput("image", "connect exactly one of 'image' and 'mask'")
        px = image.pixels if image is not None else mask.alpha[:, :, None]
        port = "image" if image is not None else "mask"
        if p.exposure != 0.0:
            try:
                gain = 2.0 ** p.exposure
            except OverflowError:
                raise BadInput("exposure", f"2**{p.exposure:g} is beyond the range of floating point") from None
            px = px.astype(np.float64) * gain  # float64: no overflow to Inf before the range check
        bad = finite_or_message(px)
        if bad:
            raise BadInput(port, f"holds {bad}" + (" after exposure" if p.exposure else "")
                           + ": an image file with them cannot be read back")
        ext = PurePosixPath(p.path).suffix.lower()
        bits = p.bits
        if ext in (".exr", ".hdr", ".tif", ".tiff"):
            half = ext == ".exr" and bits == 16
            limit = HALF_MAX if half else FLOAT32_MAX
            big = np.abs(px) > limit
            n = int(np.count_nonzero(big))
            if n:
                if p.overflow == "float32" and half:
                    bits = 32
                elif p.overflow == "clamp":
                    px = np.clip(px, -limit, limit)
                else:
                    fmt = "half-float EXR (bits: 16)" if half else "32-bit float"
                    fix = ("set overflow: clamp or overflow: float32, or bits: 32" if half else "lower the exposure")
                    raise BadInput(port, f"{n} values exceed the largest {fmt} value {limit:g} (largest "
                                   f"{float(np.abs(px).max()):g}"
                                   + (" after exposure" if p.exposure else "") + f"); {fix}")
        meta = {"graphkit:key": self.ctx.key, "graphkit:recipe": self.ctx.recipe_digest,
                "graphkit:graph": self.ctx.graph_name}
        px = np.clip(px, -FLOAT32_MAX, FLOAT32_MAX).astype(np.float32, copy=False)  # PNG/JPEG clip anyway
        return File(p.path, encode_image(px, ext, bits, meta, srgb=image is not None))
