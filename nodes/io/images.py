"""LoadImage / SaveImage through OpenImageIO (PNG, JPEG, EXR, HDR, TIFF, …)."""
from __future__ import annotations

import os
import tempfile
from pathlib import PurePosixPath
from typing import Literal

import numpy as np
from pydantic import field_validator

from graphkit import BadInput, Field, File, Image, InputFile, Node, OutputPath

BUILTIN = {
    # name -> (package, path inside it, description)
    "astronaut": ("skimage", "data/astronaut.png", "scikit-image's astronaut photo (NASA, public domain)"),
}
INTEGER_FORMATS = ("uint8", "uint16", "int8", "int16", "uint32", "int32")
WRITE_EXTS = (".exr", ".png", ".jpg", ".jpeg", ".hdr", ".tif", ".tiff")


def builtin_path(name: str) -> str:
    """Path of a ``builtin:NAME`` image shipped inside an installed package."""
    from importlib.resources import files

    if name not in BUILTIN:
        raise BadInput("path", f"unknown builtin image 'builtin:{name}' (known: "
                       + ", ".join(f"builtin:{k}" for k in BUILTIN) + ")")
    pkg, rel, _ = BUILTIN[name]
    try:
        return str(files(pkg) / rel)
    except ModuleNotFoundError:
        raise BadInput("path", f"builtin:{name} needs the package '{pkg}', which is not installed") from None


def read_image(path: str, port: str = "path") -> tuple[np.ndarray, bool]:
    """Read any OIIO-readable file → (float32 H×W×C array, whether it is integer-encoded)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        msg = oiio.geterror() or "unknown format"
        raise BadInput(port, f"cannot read image {path}: {msg.strip()}")
    try:
        spec = inp.spec()
        px = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if px is None:
            raise BadInput(port, f"cannot read image {path}: {inp.geterror().strip() or 'read failed'}")
        integer = str(spec.format) in INTEGER_FORMATS
    finally:
        inp.close()
    px = np.asarray(px, dtype=np.float32)
    if px.ndim == 2:
        px = px[:, :, None]
    return px, integer


def encode_image(pixels: np.ndarray, ext: str, bits: int = 16, metadata: dict | None = None) -> bytes:
    """Encode linear float pixels as a file's bytes: EXR/HDR/TIFF keep linear floats;
    PNG/JPEG are sRGB-encoded, clipped to [0, 1] and rounded to 8 (or 16, PNG) bits."""
    import OpenImageIO as oiio

    from nodes.common.color import linear_to_srgb

    ext = ext.lower()
    h, w, c = pixels.shape
    if ext in (".png", ".jpg", ".jpeg"):
        enc = np.clip(linear_to_srgb(np.clip(pixels, 0, None)), 0.0, 1.0)
        if ext == ".png" and bits == 16:
            data, fmt = np.round(enc * 65535).astype(np.uint16), "uint16"
        else:
            data, fmt = np.round(enc * 255).astype(np.uint8), "uint8"
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


class LoadImage(Node):
    """Read an image file with OpenImageIO into a linear float32 Image.

    8/16-bit files (PNG, JPEG, TIFF) are sRGB-decoded to linear unless ``colorspace`` says
    otherwise; float files (EXR, HDR) are taken as linear.  ``builtin:astronaut`` names
    scikit-image's astronaut photograph.  Files with NaN or Inf values are refused.
    """

    version = "1"
    outputs = {"image": Image}

    class Params(Node.Params):
        path: InputFile = Field(description="image file, relative to the graph file, or builtin:NAME")
        colorspace: Literal["auto", "srgb", "linear"] = Field(
            "auto", description="encoding of the file's values: auto = sRGB for integer files, linear for float")
        drop_alpha: bool = Field(True, description="keep only the first three channels of RGBA files")

    @classmethod
    def resolve_file(cls, param, value, base_dir):
        if value.startswith("builtin:"):
            return builtin_path(value[len("builtin:"):])
        return super().resolve_file(param, value, base_dir)

    def compute(self):
        from graphkit.types import finite_or_message
        from nodes.common.color import srgb_to_linear

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        px, integer = read_image(path)
        if self.params.drop_alpha and px.shape[2] == 4:
            px = px[:, :, :3]
        bad = finite_or_message(px)
        if bad:
            raise BadInput("path", f"{path} holds {bad}")
        cs = self.params.colorspace
        if cs == "srgb" or (cs == "auto" and integer):
            px = srgb_to_linear(px)
        return Image(px, "lin_srgb")


class SaveImage(Node):
    """Encode an Image as a file in the run's output folder (EXR, PNG, JPEG, HDR, TIFF).

    The file carries provenance in its metadata: ``graphkit:key`` (the cache key of this
    result) and ``graphkit:recipe`` (digest of the part of the graph that produced it).
    """

    version = "2"  # 2: no DateTime stamp (reproducible bytes)
    provenance = True
    inputs = {"image": Image}
    outputs = {"file": File}

    class Params(Node.Params):
        path: OutputPath = Field(description="file name inside --out, e.g. relit/front.exr; the extension picks the format")
        bits: Literal[8, 16, 32] = Field(16, description="EXR: 16 (half) or 32 (float); PNG: 8 or 16")
        exposure: float = Field(0.0, description="stops added before encoding")

        @field_validator("path")
        @classmethod
        def _relative(cls, v: str) -> str:
            p = PurePosixPath(v.replace("\\", "/"))
            if p.is_absolute() or ".." in p.parts or not p.parts or ":" in v:
                raise ValueError("must be a relative path inside the output folder (no '..', no absolute path)")
            if p.suffix.lower() not in WRITE_EXTS:
                raise ValueError(f"unknown extension {p.suffix!r}; use one of {', '.join(WRITE_EXTS)}")
            return str(p)

    def compute(self, image: Image):
        px = image.pixels * np.float32(2.0 ** self.params.exposure)
        meta = {"graphkit:key": self.ctx.key, "graphkit:recipe": self.ctx.recipe_digest,
                "graphkit:graph": self.ctx.graph_name}
        ext = PurePosixPath(self.params.path).suffix
        return File(self.params.path, encode_image(px, ext, self.params.bits, meta))
